"""Evaluate the text-guided DDPM on real heads (ICT-FaceKit), on renders; one JSON line per figure.

Data: ``--data DIR``, a ``geoface dataset ict`` output (manifest rows with ``labels``:
``expression_name`` and ``split`` by identity).  The DDPM trains on the ``train`` identities
only (``OUT/train_data``: a manifest + links), unless ``--run`` names a trained run.

Every real item and every sample goes the same way: decoded in the run's dataset frame,
aligned to the mean training head by the best similarity transform over its pixels (a run
trained with rigid augmentation samples heads in any pose), reconstructed to a mesh and
rendered off-screen in grey from fixed cameras (front and three-quarter) under fixed lights
(:class:`geoface.ddpm.render.HeadRenderer`).

Figures:

* validity — share of samples (and of real items, through the same path) that reconstruct to a
  clean manifold disk;
* text control — an expression classifier (a small CNN on the renders) trained on real heads of
  the training identities, its accuracy on the held-out identities, and for each preset prompt
  the share of its samples the classifier assigns to the prompt's expression; against chance
  and against unconditional samples (guidance 0: how often the expression comes up unasked);
* diversity — Vendi score (cosine similarity of centred renders) of each prompt's samples and of
  as many real renders of that expression;
* memorisation — nearest-training-neighbour RMS position distance (after the best similarity
  transform, in units of the dataset frame) of the samples, against that of the held-out real heads.

    python bench/eval_ddpm.py --data ict64/ --res 64 --minutes 60 --threads 1 --out bench/results/ddpm_ict/res64
    python bench/eval_ddpm.py --data ict64/ --run run64/ --out /tmp/eval64    # evaluate a trained run
    python bench/eval_ddpm.py --quick --out /tmp/ddpm_quick                  # smoke test (builds 36 heads)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from geoface.errors import GeofaceError  # noqa: E402

RESULTS: list[dict] = []


def emit(**d):
    RESULTS.append(d)
    print(json.dumps({k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in d.items()}), flush=True)


def read_items(data_dir: Path) -> list[dict]:
    """Manifest rows (status ok, last row per item) with an ``expression_name`` label."""
    man = data_dir / "manifest.jsonl"
    if not man.is_file():
        raise GeofaceError(f"{data_dir} has no manifest.jsonl (need a `geoface dataset ict` output)")
    last = {}
    for line in man.read_text(encoding="utf-8").splitlines():
        if line.strip():
            row = json.loads(line)
            last[row.get("item")] = row
    rows = [r for k, r in sorted(last.items()) if k and r.get("status") == "ok" and (data_dir / k / "meta.json").is_file()]
    rows = [r for r in rows if (r.get("labels") or {}).get("expression_name")]
    if len(rows) < 4:
        raise GeofaceError(f"{data_dir}: need labelled items (manifest 'labels' with 'expression_name'); found {len(rows)}")
    return rows


def write_split(data_dir: Path, rows: list[dict], idx, out: Path) -> Path:
    """A dataset folder holding only ``rows[idx]``: manifest + symbolic links to the item folders."""
    out.mkdir(parents=True, exist_ok=True)
    lines = []
    for i in idx:
        r = rows[i]
        link = out / r["item"]
        link.parent.mkdir(parents=True, exist_ok=True)
        if not link.exists():
            os.symlink((data_dir / r["item"]).resolve(), link)
        lines.append(json.dumps(r))
    (out / "manifest.jsonl").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return out


class Judge:
    """Align → reconstruct → render, the same for real items and samples."""

    def __init__(self, state: dict, ref: np.ndarray, size: int, views):
        from geoface.ddpm.data import Normalization
        from geoface.ddpm.render import HeadRenderer

        self.state = state
        self.support = None  # pixels every training item covers (set once the real items are read)
        nz = Normalization.from_dict(state["normalization"])
        self.ref = ref  # (R*R, 3) mean training head, normalised
        c = np.asarray(nz.center) + np.array([0.0, 0.32, 0.0]) * nz.scale  # the face and the top of the head
        self.renderer = HeadRenderer(center=c, scale=0.62 * nz.scale, size=size, views=views)

    def align(self, X: np.ndarray, support=None) -> np.ndarray:
        """Positions of ``X [n, C, R, R]`` (normalised) moved onto the reference by a similarity;
        zero outside the coverage mask (``|normal| > 0.5``, or ``support``)."""
        from geoface.ddpm.render import similarity_align

        out = X.copy()
        for k, x in enumerate(X):
            R = x.shape[-1]
            P = x[:3].reshape(3, -1).T
            m = np.linalg.norm(x[3:6].reshape(3, -1).T, axis=1) > 0.5
            if support is not None:
                m = m | np.asarray(support, bool).reshape(-1)
            out[k, :3] = similarity_align(P, self.ref, m).T.reshape(3, R, R) * m.reshape(R, R)[None]
        return out

    def support_validity(self, X: np.ndarray) -> list:
        """Validity with the coverage mask completed by the data's support (pixels every training
        item covers count as covered), the rest as :meth:`__call__`."""
        import torch

        from geoface.ddpm import evaluate as ev
        from geoface.ddpm.model import to_geometry_images

        return [ev.mesh_validity(g) for g in to_geometry_images(torch.from_numpy(self.align(X, self.support)), self.state,
                                                                 self.support)]

    def __call__(self, X: np.ndarray):
        """``(renders [n, views, S, S], validity list)`` of normalised images ``X``."""
        import torch

        from geoface.gimage import reconstruct
        from geoface.ddpm import evaluate as ev
        from geoface.ddpm.model import to_geometry_images

        gis = to_geometry_images(torch.from_numpy(self.align(X)), self.state)
        val, imgs = [], []
        for g in gis:
            v = ev.mesh_validity(g)
            val.append(v)
            if v.reconstructs:
                rec = reconstruct(g)
                imgs.append(self.renderer.render(rec.V, rec.F))
            else:
                imgs.append(np.zeros((len(self.renderer.views), self.renderer.size, self.renderer.size), np.float32))
        return np.stack(imgs).astype(np.float32), val


def vendi_of(R: np.ndarray, mean: np.ndarray) -> float:
    from geoface.ddpm import evaluate as ev
    return ev.vendi_score(ev.cosine_similarity((R - mean[None]).reshape(len(R), -1)))


def choose_sampling(a, drun, judge, clf, classes, sample, ev) -> tuple[str, int, float]:
    """``(scheduler, steps, guidance)``: the ``--select`` setting whose validation samples (seeds
    from ``a.seed + 10_000``) are most often valid (coverage completed by the support), then
    best follow their prompt; one ``validation`` line per setting."""
    from geoface.synth.ict_data import PRESET_PROMPTS

    if not a.select:
        return "ddim", a.sample_steps, a.guidance
    scored = []
    for spec in a.select:
        try:
            name, steps, guidance = spec.split(":")
            setting = (name, int(steps), float(guidance))
        except ValueError:
            raise GeofaceError(f"--select: {spec!r} is not SCHED:STEPS:GUIDANCE (e.g. ddim:50:3)") from None
        t = time.perf_counter()
        valid, hits = [], []
        for k, cls in enumerate(classes):
            x = sample(drun, PRESET_PROMPTS[cls], n=a.val_per_prompt, steps=setting[1], scheduler=setting[0],
                       guidance=setting[2], seed=a.seed + 10_000 + k, device=a.device, quiet=True).numpy()
            valid += [v.valid for v in judge.support_validity(x)]
            hits += list(ev.predict(clf, judge(x)[0]) == k)
        score = (float(np.mean(valid)), float(np.mean(hits)))
        scored.append((score, setting))
        emit(case="validation", setting=spec, n=len(valid), valid_rate_support=score[0], text_accuracy=score[1],
             seconds=time.perf_counter() - t)
    best = max(scored, key=lambda s: s[0])[1]
    emit(case="chosen", scheduler=best[0], steps=best[1], guidance=best[2])
    return best


def build_quick_data(root: Path) -> Path:
    from geoface.dataset import DatasetOptions, build_ict_dataset
    build_ict_dataset(root / "data", 36, DatasetOptions(res=16, augment=1, preview=False), seed=0, mix_share=0.0,
                      workers=2, quiet=True)
    return root / "data"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, help="a `geoface dataset ict` output")
    ap.add_argument("--res", type=int, default=64, help="training resolution (divides the dataset's)")
    ap.add_argument("--run", type=Path, help="existing trained run; default: train one")
    ap.add_argument("--run-dir", type=Path, help="where a run trained here is written (default OUT/run)")
    ap.add_argument("--resume", action="store_true",
                    help="continue the run in --run-dir (or OUT/run) for --minutes more, then evaluate it")
    ap.add_argument("--minutes", type=float, default=60.0, help="training budget (wall clock)")
    ap.add_argument("--steps", type=int, default=1_000_000, help="training step cap")
    ap.add_argument("--model", default="small", help="DDPM preset (small, base, tiny)")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--augment", action="store_true", help="train with rigid augmentation")
    ap.add_argument("--no-standardize", action="store_true",
                    help="ablation: denoise the raw dataset-frame channels (the paper's set-up) instead of standardised ones")
    ap.add_argument("--patch", type=int, default=1, help="pixel blocks folded into channels (DDPMConfig.patch)")
    ap.add_argument("--prediction", default="epsilon", help="epsilon | v_prediction | sample")
    ap.add_argument("--schedule-shift", type=float, default=1.0, help="noise-schedule shift (DDPMConfig.schedule_shift)")
    ap.add_argument("--stats-per-pixel", action="store_true", help="standardise per pixel (DDPMConfig.stats_per_pixel)")
    ap.add_argument("--lr-schedule", default="constant", help="constant | cosine (over --steps)")
    ap.add_argument("--ema-decay", type=float, default=None, help="EMA decay (default: the preset's)")
    ap.add_argument("--text", default="minilm", help="text encoder: minilm | clip:PATH | hash[:DIM]")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads for training")
    ap.add_argument("--eval-threads", type=int, default=None, help="torch CPU threads for sampling and judging (default: --threads)")
    ap.add_argument("--samples-per-prompt", type=int, default=16)
    ap.add_argument("--sample-steps", type=int, default=50)
    ap.add_argument("--guidance", type=float, default=3.0)
    ap.add_argument("--select", nargs="+", default=None, metavar="SCHED:STEPS:GUIDANCE",
                    help="sampling settings to choose from on validation samples (other seeds than the "
                         "reported ones), e.g. ddim:50:3 ddim:50:1.5 ddpm:200:3; the most valid wins, then "
                         "the best text control; default: ddim with --sample-steps and --guidance")
    ap.add_argument("--val-per-prompt", type=int, default=4, help="validation samples per prompt and setting")
    ap.add_argument("--render-size", type=int, default=64)
    ap.add_argument("--views", nargs="+", default=["front", "three_quarter"])
    ap.add_argument("--classifier-epochs", type=int, default=40)
    ap.add_argument("--grid-columns", type=int, default=8, help="samples per prompt in the picture")
    ap.add_argument("--out", type=Path, required=True, help="results.json and pictures go here")
    ap.add_argument("--quick", action="store_true", help="tiny smoke configuration (a few minutes)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    try:
        return run(a)
    except GeofaceError as e:
        print(f"eval_ddpm: error: {e}", file=sys.stderr)
        return 2


def run(a) -> int:
    import cv2
    import torch

    from geoface.ddpm import evaluate as ev
    from geoface.ddpm.data import GImageDataset, Normalization
    from geoface.ddpm.model import DDPMConfig, load_run, sample, train
    from geoface.ddpm.render import grid_image
    from geoface.synth.ict_data import PRESET_PROMPTS

    tmp = tempfile.TemporaryDirectory(prefix="eval_ddpm_")
    work = Path(tmp.name)
    if a.quick:
        a.res, a.minutes, a.steps, a.batch, a.model = 16, 0.5, 30, 4, "tiny"
        a.samples_per_prompt, a.sample_steps, a.classifier_epochs, a.render_size = 3, 5, 5, 32
        a.text = a.text if a.text != "minilm" else "hash:32"
        if a.data is None:
            a.data = build_quick_data(work)
    if a.data is None or not a.data.is_dir():
        raise GeofaceError(f"--data: a dataset folder is needed; got {a.data}")
    if a.device == "cuda" and not torch.cuda.is_available():
        raise GeofaceError("--device cuda: no CUDA device is available")
    if a.run is not None and not (a.run / "checkpoint" / "config.json").is_file() and not (a.run / "config.json").is_file():
        raise GeofaceError(f"--run: no checkpoint (config.json) in {a.run}")
    torch.set_num_threads(int(a.threads))
    a.out.mkdir(parents=True, exist_ok=True)
    rows = read_items(a.data)
    split = np.array([(r["labels"].get("split") or "train") for r in rows])
    labels = np.array([r["labels"]["expression_name"] for r in rows])
    tr, ho = np.flatnonzero(split == "train"), np.flatnonzero(split != "train")
    emit(case="split", items=len(rows), train=len(tr), held_out=len(ho), per_class=dict(Counter(labels.tolist())))

    # ---- the model
    if a.run is None:
        train_dir = write_split(a.data, rows, tr, work / "train_data")
        cfg = DDPMConfig.preset(a.model, res=a.res, text_encoder=a.text, batch_size=a.batch, steps=a.steps,
                                checkpoint_every=200, seed=a.seed, augment=bool(a.augment),
                                standardize=not a.no_standardize, patch=a.patch, prediction=a.prediction,
                                schedule_shift=a.schedule_shift, stats_per_pixel=a.stats_per_pixel,
                                lr_schedule=a.lr_schedule,
                                **({"ema_decay": a.ema_decay} if a.ema_decay is not None else {}))
        run_dir = a.run_dir or (a.out / "run" if not a.quick else work / "run")
        before = {}
        if a.resume:
            if not (run_dir / "checkpoint" / "state.json").is_file():
                raise GeofaceError(f"--resume: no checkpoint in {run_dir}")
            if (run_dir / "train_info.json").is_file():
                before = json.loads((run_dir / "train_info.json").read_text(encoding="utf-8"))
        t = time.perf_counter()
        last = train(train_dir, run_dir, cfg, device=a.device, quiet=True, max_seconds=60 * a.minutes, resume=a.resume)
        info = {"steps": last["step"], "seconds": time.perf_counter() - t + float(before.get("seconds", 0.0)),
                "steps_per_second": last["steps_per_second"],
                "threads": torch.get_num_threads(), "device": a.device, "batch": a.batch, "final_loss": last["loss"],
                "losses": last["losses"], "model": a.model, "augment": bool(a.augment), "text_encoder": cfg.text_encoder,
                "standardize": cfg.standardize, "patch": cfg.patch, "prediction": cfg.prediction,
                "schedule_shift": cfg.schedule_shift, "stats_per_pixel": cfg.stats_per_pixel,
                "lr_schedule": cfg.lr_schedule, "ema_decay": cfg.ema_decay,
                "train_items": len(tr)}
        (run_dir / "train_info.json").write_text(json.dumps(info), encoding="utf-8")
        emit(case="train", **info)
    else:
        run_dir = a.run
        if (run_dir / "train_info.json").is_file():
            emit(case="train", reused=True, **json.loads((run_dir / "train_info.json").read_text(encoding="utf-8")))
    torch.set_num_threads(int(a.eval_threads or a.threads))
    drun = load_run(run_dir)
    cfg = drun.config
    if "normalization" not in drun.state:
        raise GeofaceError(f"{run_dir} was trained before dataset normalisation existed; train it again")
    emit(case="run", run=str(run_dir), step=drun.state.get("step"), res=cfg.res, modalities=list(cfg.modalities),
         params=sum(p.numel() for p in drun.unet.parameters()), trained_on_items=drun.state.get("items"))

    # ---- real items, in the run's frame
    t = time.perf_counter()
    ds = GImageDataset(a.data, res=cfg.res, normalization=Normalization.from_dict(drun.state["normalization"]),
                       modalities=tuple(cfg.modalities), cache_mb=0)
    index = {str(it.folder.relative_to(a.data)): k for k, it in enumerate(ds.items)}
    X = np.stack([ds[index[r["item"]]]["image"].numpy() for r in rows]).astype(np.float32)
    M = np.linalg.norm(X[:, 3:6], axis=1) > 0.5
    R = X.shape[-1]
    ref = X[tr, :3].mean(0).reshape(3, -1).T
    judge = Judge(drun.state, ref, a.render_size, a.views)
    judge.support = M[tr].all(axis=0)  # every training head covers these pixels (all of them for ICT heads)
    real_r, real_v = judge(X)
    emit(case="real_renders", items=len(X), seconds=time.perf_counter() - t,
         valid_rate=float(np.mean([v.valid for v in real_v])), reasons=dict(Counter(v.reason for v in real_v if not v.valid)))
    mean_render = real_r[tr].mean(0)

    # ---- the classifier: preset expressions, training identities -> held-out identities
    classes = [c for c in PRESET_PROMPTS if c in set(labels.tolist())]
    cls_tr = np.array([i for i in tr if labels[i] in classes])
    cls_ho = np.array([i for i in ho if labels[i] in classes])
    y = np.array([classes.index(c) if c in classes else -1 for c in labels])
    t = time.perf_counter()
    clf = ev.train_classifier(real_r[cls_tr], y[cls_tr], n_classes=len(classes), epochs=a.classifier_epochs,
                              seed=a.seed, augment_shift=max(1, a.render_size // 32))
    acc_ho = float(np.mean(ev.predict(clf, real_r[cls_ho]) == y[cls_ho])) if len(cls_ho) else float("nan")
    per_class_ho = {c: float(np.mean(ev.predict(clf, real_r[cls_ho[y[cls_ho] == k]]) == k)) if np.any(y[cls_ho] == k) else None
                    for k, c in enumerate(classes)}
    emit(case="classifier", classes=len(classes), chance=1.0 / len(classes), train_items=len(cls_tr),
         held_out_items=len(cls_ho), held_out_accuracy=acc_ho, train_accuracy=float(np.mean(ev.predict(clf, real_r[cls_tr]) == y[cls_tr])),
         held_out_per_class=per_class_ho, epochs=a.classifier_epochs, seconds=time.perf_counter() - t)

    # ---- memorisation baseline: held-out real -> training
    d_ho, _ = ev.nearest_neighbour(X[ho, :3], M[ho], X[tr, :3], M[tr], aligned=True)
    emit(case="nn_baseline", what="held-out real -> train (aligned RMS, dataset frame)", n=len(ho), mean=float(d_ho.mean()),
         median=float(np.median(d_ho)), min=float(d_ho.min()))

    # ---- sampling settings, chosen on validation samples (seeds the reported samples do not use)
    sched_name, a.sample_steps, a.guidance = choose_sampling(a, drun, judge, clf, classes, sample, ev)

    # ---- unconditional samples: how often each expression comes up unasked
    n = a.samples_per_prompt
    t = time.perf_counter()
    xu = sample(drun, "", n=n, steps=a.sample_steps, scheduler=sched_name, guidance=0.0, seed=a.seed + 999,
                device=a.device, quiet=True)
    ru, vu = judge(xu.numpy())
    vus = judge.support_validity(xu.numpy())
    pu = ev.predict(clf, ru)
    uncond = Counter(classes[p] for p in pu)
    emit(case="unconditional", n=n, seconds=time.perf_counter() - t, valid_rate=float(np.mean([v.valid for v in vu])),
         valid_rate_support=float(np.mean([v.valid for v in vus])), predicted=dict(uncond))

    # ---- samples per preset prompt
    rng = np.random.default_rng(a.seed)
    summary, grid, grid2 = [], [], []
    for k, cls in enumerate(classes):
        prompt = PRESET_PROMPTS[cls]
        t = time.perf_counter()
        x = sample(drun, prompt, n=n, steps=a.sample_steps, scheduler=sched_name, guidance=a.guidance, seed=a.seed + k,
                   device=a.device, quiet=True)
        secs = time.perf_counter() - t
        S = x.numpy()
        rs, val = judge(S)
        val_s = judge.support_validity(S)
        SM = np.linalg.norm(S[:, 3:6], axis=1) > 0.5
        pred = ev.predict(clf, rs)
        same = np.flatnonzero(labels == cls)
        ref_idx = rng.choice(same, size=min(len(same), n), replace=False)
        d, j = ev.nearest_neighbour(S[:, :3], SM, X[tr, :3], M[tr], aligned=True)
        rec = dict(case="prompt", prompt=prompt, expression=cls, n=n, sample_seconds=secs,
                   valid_rate=float(np.mean([v.valid for v in val])),
                   invalid_reasons=dict(Counter(v.reason for v in val if not v.valid)),
                   valid_rate_support=float(np.mean([v.valid for v in val_s])),
                   invalid_reasons_support=dict(Counter(v.reason for v in val_s if not v.valid)),
                   text_accuracy=float(np.mean(pred == k)), chance=1.0 / len(classes),
                   unconditional_rate=uncond.get(cls, 0) / n, predicted=dict(Counter(classes[p] for p in pred)),
                   vendi_samples=vendi_of(rs, mean_render), vendi_real=vendi_of(real_r[ref_idx], mean_render),
                   vendi_real_n=len(ref_idx), nn_mean=float(d.mean()), nn_min=float(d.min()),
                   nn_train_items=len({rows[tr[i]]["item"] for i in j}))
        emit(**rec)
        summary.append(rec)
        cols = min(a.grid_columns, n)
        real_one = real_r[ref_idx[0], 0] if len(ref_idx) else np.zeros_like(rs[0, 0])
        grid.append(np.concatenate([rs[:cols, 0], real_one[None]], 0))
        if len(a.views) > 1:
            grid2.append(np.concatenate([rs[:cols, 1], real_r[ref_idx[0], 1][None] if len(ref_idx) else rs[:1, 1] * 0], 0))
    rows_l = [PRESET_PROMPTS[c] for c in classes]
    cols_l = ["samples"] + [""] * (min(a.grid_columns, n) - 1) + ["real"]
    cv2.imwrite(str(a.out / "samples_grid.png"), grid_image(np.stack(grid), row_labels=rows_l, col_labels=cols_l))
    if len(a.views) > 1:
        cv2.imwrite(str(a.out / f"samples_grid_{a.views[1]}.png"),
                    grid_image(np.stack(grid2), row_labels=rows_l, col_labels=cols_l))
    allv = [r["valid_rate"] for r in summary]
    emit(case="summary", res=cfg.res, prompts=len(summary), samples=sum(r["n"] for r in summary),
         valid_rate=float(np.mean(allv)), valid_rate_real=float(np.mean([v.valid for v in real_v])),
         valid_rate_support=float(np.mean([r["valid_rate_support"] for r in summary])),
         support_pixels=float(judge.support.mean()),
         text_accuracy_mean=float(np.mean([r["text_accuracy"] for r in summary])),
         unconditional_rate_mean=float(np.mean([r["unconditional_rate"] for r in summary])),
         classifier_held_out_accuracy=acc_ho, chance=1.0 / len(classes),
         vendi_samples_mean=float(np.mean([r["vendi_samples"] for r in summary])),
         vendi_real_mean=float(np.mean([r["vendi_real"] for r in summary])),
         nn_samples_mean=float(np.mean([r["nn_mean"] for r in summary])), nn_held_out_mean=float(d_ho.mean()))
    args = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(a).items()}
    (a.out / "results.json").write_text(json.dumps({"args": args, "results": RESULTS}, indent=1), encoding="utf-8")
    judge.renderer.close()
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
