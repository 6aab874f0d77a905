"""Evaluate the text-guided DDPM on labelled synthetic heads; one JSON line per figure.

Data: ``--data DIR`` (a ``geoface dataset build`` output whose manifest rows carry ``labels``
with ``expression_name``) or ``--count`` heads made by ``data_tools/make_synthetic_heads.py`` and
built at ``--res``.  The items are split per expression class (seed 0, 20 % held out); the DDPM
trains on the training split only (``OUT/train_data``: a manifest + links), unless ``--run``
names a trained run.

Figures (see :mod:`geoface.learn.evaluate`):

* validity — share of samples (and of real items, through the same path) that reconstruct to a
  clean manifold disk;
* text control — an expression CNN trained on the real training images, its held-out accuracy,
  and the share of each prompt's samples it assigns to the prompt's expression (chance = 1/classes);
* diversity — Vendi score (cosine similarity of centred position+normal features) of each
  prompt's samples and of as many real images of that expression;
* memorisation — nearest-training-neighbour RMS position distance of the samples vs. that of the
  held-out real items, plainly and after the best similarity transform (a run trained with rigid
  augmentation samples heads in rotated, shifted, scaled poses; the aligned distance sees through
  that).  The classifier then trains on rigidly augmented copies too (``--classifier-augment``).

    python bench/eval_ddpm.py --out bench/results/ddpm_eval --count 200 --minutes 22
    python bench/eval_ddpm.py --quick --out /tmp/ddpm_quick
"""

from __future__ import annotations

import argparse
import importlib.util
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


def build_data(root: Path, count: int, res: int, seed: int) -> Path:
    from geoface.dataset import DatasetOptions, build_dataset
    spec = importlib.util.spec_from_file_location("make_synthetic_heads", REPO / "data_tools" / "make_synthetic_heads.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    t = time.perf_counter()
    tool.make_synthetic_heads(root / "heads", count=count, seed=seed)
    t_heads = time.perf_counter() - t
    s = build_dataset(root / "heads", root / "data", DatasetOptions(res=res, augment=1), workers=1, quiet=True)
    emit(case="dataset", count=count, res=res, built=s["done"], failed=s["failed"], heads_seconds=t_heads,
         build_seconds=s["seconds"], workers=1)
    return root / "data"


def read_items(data_dir: Path) -> list[dict]:
    """Manifest rows (status ok, last row per item) with an ``expression_name`` label."""
    man = data_dir / "manifest.jsonl"
    if not man.is_file():
        raise GeofaceError(f"{data_dir} has no manifest.jsonl (need a `geoface dataset build` output)")
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


def load_real(data_dir: Path, rows: list[dict], res: int):
    """``X [n, 9, R, R]`` in [-1, 1], ``M [n, R, R]`` bool (the dataset loader's convention)."""
    from geoface.learn.data import area_resize
    from geoface.gimage import load_gimage
    X, M = [], []
    for r in rows:
        gi = load_gimage(data_dir / r["item"])
        img = np.concatenate([gi.modality(m) for m in ("position", "normal", "texture")], 0).astype(np.float32)
        img, m = area_resize(img, np.asarray(gi.mask, bool), res)
        X.append((img * 2 - 1) * m[None])
        M.append(m)
    return np.stack(X).astype(np.float32), np.stack(M)


def augmented(X: np.ndarray, M: np.ndarray, y: np.ndarray, copies: int, seed: int):
    """``X`` followed by ``copies`` rigidly augmented copies (the training loader's rigid_augment)."""
    import torch

    from geoface.learn.data import rigid_augment
    if copies <= 0:
        return X, y
    g = torch.Generator().manual_seed(int(seed))
    out = [X]
    for _ in range(copies):
        out.append(np.stack([rigid_augment(torch.from_numpy(x), torch.from_numpy(m), g).numpy() for x, m in zip(X, M)]))
    return np.concatenate(out).astype(np.float32), np.tile(y, copies + 1)


def as_model_space(gis) -> tuple[np.ndarray, np.ndarray]:
    """Geometry images (after clamping and masking) back to ``[n, 9, R, R]`` in [-1, 1] + masks."""
    X = np.stack([(g.image * 2 - 1) * g.mask[None] for g in gis]).astype(np.float32)
    return X, np.stack([np.asarray(g.mask, bool) for g in gis])


def features(X: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Position+normal channels, 4x4 average-pooled, centred on the real training mean."""
    x = X[:, :6] - mean[None, :6]
    n, c, h, w = x.shape
    return x.reshape(n, c, h // 4, 4, w // 4, 4).mean((3, 5)).reshape(n, -1)


def montage(path: Path, X: np.ndarray, title_rows: int = 3) -> None:
    """Rows position / normal / texture, one column per image, 2x nearest upscaling, 8-bit PNG."""
    import cv2
    tiles = []
    for s in (slice(0, 3), slice(3, 6), slice(6, 9)):
        row = [np.pad(np.clip((x[s] + 1) / 2, 0, 1).transpose(1, 2, 0), ((1, 1), (1, 1), (0, 0)), constant_values=1) for x in X]
        tiles.append(np.concatenate(row, 1))
    img = np.concatenate(tiles, 0)
    img = np.repeat(np.repeat(img, 2, 0), 2, 1)
    cv2.imwrite(str(path), np.round(img[..., ::-1] * 255).astype(np.uint8))


def choose_prompts(rows, train_idx, classes, min_items: int, k: int) -> list[tuple[str, str]]:
    """One prompt per expression class with >= ``min_items`` training items: the class's most
    common training prompt (shortest on ties); the ``k`` largest classes."""
    by = Counter(rows[i]["labels"]["expression_name"] for i in train_idx)
    out = []
    for c, n in sorted(by.items(), key=lambda t: (-t[1], t[0])):
        if n < min_items or c not in classes:
            continue
        ps = Counter(rows[i].get("prompt", "") for i in train_idx if rows[i]["labels"]["expression_name"] == c)
        p = sorted(ps.items(), key=lambda t: (-t[1], len(t[0]), t[0]))[0][0]
        out.append((p, c))
    return out[:k]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, help="existing dataset (manifest with labels); default: build one")
    ap.add_argument("--count", type=int, default=200, help="synthetic heads to build when --data is not given")
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--run", type=Path, help="existing trained run; default: train one")
    ap.add_argument("--minutes", type=float, default=20.0, help="training budget (wall clock)")
    ap.add_argument("--steps", type=int, default=100000, help="training step cap")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--channels", default="32,64,96,128", help="UNet block_out_channels")
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--text", default="minilm", help="text encoder: minilm | clip:PATH | hash[:DIM]")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("--samples-per-prompt", type=int, default=8)
    ap.add_argument("--sample-steps", type=int, default=50)
    ap.add_argument("--guidance", type=float, default=3.0)
    ap.add_argument("--clip", type=float, default=1.0, help="clamp the x0 estimate to [-clip, clip] while sampling (0 = off)")
    ap.add_argument("--prompts", nargs="*", help="prompts to sample (default: one per expression class)")
    ap.add_argument("--n-prompts", type=int, default=5)
    ap.add_argument("--classifier-epochs", type=int, default=120)
    ap.add_argument("--classifier-augment", type=int, default=4,
                    help="rigidly augmented copies of each classifier training item when the run trained with "
                         "augmentation (its samples come in augmented poses)")
    ap.add_argument("--classifier-shift", type=int, default=None,
                    help="random shift augmentation of the classifier, pixels (default: res // 64; at N = 32 "
                         "a one-pixel shift costs it most of its held-out accuracy)")
    ap.add_argument("--out", type=Path, required=True, help="results.json and preview PNGs go here")
    ap.add_argument("--quick", action="store_true", help="tiny smoke configuration (about a minute)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    try:
        return run(a)
    except GeofaceError as e:
        print(f"eval_ddpm: error: {e}", file=sys.stderr)
        return 2


def run(a) -> int:
    import torch

    from geoface.learn import evaluate as ev
    from geoface.learn.ddpm import DDPMConfig, load_run, sample, to_geometry_images, train

    if a.quick:
        a.count, a.res, a.minutes, a.steps, a.batch = 24, 16, 0.5, 30, 4
        a.channels, a.samples_per_prompt, a.sample_steps, a.n_prompts, a.classifier_epochs = "16,32", 3, 5, 2, 10
        a.text = a.text if a.text != "minilm" else "hash:32"
    if a.device == "cuda" and not torch.cuda.is_available():
        raise GeofaceError("--device cuda: no CUDA device is available")
    if a.data is not None and not a.data.is_dir():
        raise GeofaceError(f"--data: folder not found: {a.data}")
    if a.run is not None and not (a.run / "checkpoint" / "config.json").is_file() and not (a.run / "config.json").is_file():
        raise GeofaceError(f"--run: no checkpoint (config.json) in {a.run}")
    torch.set_num_threads(int(a.threads))
    a.out.mkdir(parents=True, exist_ok=True)
    tmp = tempfile.TemporaryDirectory(prefix="eval_ddpm_")
    work = Path(tmp.name)
    data = a.data if a.data is not None else build_data(work, a.count, a.res, a.seed)
    rows = read_items(data)
    labels = np.array([r["labels"]["expression_name"] for r in rows])
    classes = sorted(set(labels.tolist()))
    y = np.array([classes.index(c) for c in labels])
    tr, ho = ev.stratified_split(labels, 0.2, seed=a.seed)
    emit(case="split", items=len(rows), train=len(tr), held_out=len(ho), classes=len(classes),
         per_class=dict(Counter(labels.tolist())))

    # ---- the model
    if a.run is None:
        train_dir = write_split(data, rows, tr, work / "train_data")
        cfg = DDPMConfig(res=a.res, block_out_channels=tuple(int(c) for c in a.channels.split(",")),
                         layers_per_block=1, attention_head_dim=8, norm_num_groups=8,
                         attention_levels=tuple(range(max(0, len(a.channels.split(",")) - 2), len(a.channels.split(",")))),
                         text_encoder=a.text, lr=a.lr, ema_decay=0.995, batch_size=a.batch, steps=a.steps,
                         checkpoint_every=200, seed=a.seed)
        run_dir = a.out / "run" if not a.quick else work / "run"
        t = time.perf_counter()
        last = train(train_dir, run_dir, cfg, device=a.device, quiet=True, max_seconds=60 * a.minutes)
        info = {"steps": last["step"], "seconds": time.perf_counter() - t, "threads": torch.get_num_threads(),
                "device": a.device, "batch": a.batch, "final_loss": last["loss"], "losses": last["losses"],
                "block_out_channels": list(cfg.block_out_channels), "attention_levels": list(cfg.attention_levels),
                "text_encoder": cfg.text_encoder, "train_items": len(tr)}
        (run_dir / "train_info.json").write_text(json.dumps(info), encoding="utf-8")
        emit(case="train", **info)
    else:
        run_dir = a.run
        if (run_dir / "train_info.json").is_file():  # written when this script trained the run
            emit(case="train", reused=True, **json.loads((run_dir / "train_info.json").read_text(encoding="utf-8")))
    drun = load_run(run_dir)
    emit(case="run", run=str(run_dir), step=drun.state.get("step"), params=sum(p.numel() for p in drun.unet.parameters()),
         trained_on=drun.state.get("data_dir"))

    # ---- real data, classifier
    X, M = load_real(data, rows, drun.config.res)
    mean = X[tr].mean(0)
    t = time.perf_counter()
    shift = drun.config.res // 64 if a.classifier_shift is None else int(a.classifier_shift)
    # a run trained with the paper's rigid augmentation samples heads in rotated, shifted, scaled
    # poses: the classifier then sees the same augmentation (K copies of each training item)
    n_aug = (a.classifier_augment if drun.config.augment else 0)
    Xc, yc = augmented(X[tr], M[tr], y[tr], n_aug, a.seed)
    clf = ev.train_classifier(Xc, yc, n_classes=len(classes), epochs=a.classifier_epochs, seed=a.seed,
                              augment_shift=shift)
    acc_ho = float(np.mean(ev.predict(clf, X[ho]) == y[ho])) if len(ho) else float("nan")
    Xh, yh = augmented(X[ho], M[ho], y[ho], max(n_aug, 1), a.seed + 1)
    acc_ho_aug = float(np.mean(ev.predict(clf, Xh[len(ho):]) == yh[len(ho):])) if len(ho) else float("nan")
    emit(case="classifier", shift=shift, epochs=a.classifier_epochs, augmented_copies=n_aug, held_out_accuracy=acc_ho,
         held_out_accuracy_augmented=acc_ho_aug, train_accuracy=float(np.mean(ev.predict(clf, X[tr]) == y[tr])),
         held_out=len(ho), classes=len(classes), chance=1.0 / len(classes), seconds=time.perf_counter() - t)

    state = drun.state if "bbox_min" in drun.state else {"bbox_min": [0, 0, 0], "bbox_max": [1, 1, 1]}
    real_gis = to_geometry_images(torch.from_numpy(X), state)
    real_valid = [ev.mesh_validity(g) for g in real_gis]
    emit(case="validity_real", items=len(real_gis), valid_rate=float(np.mean([v.valid for v in real_valid])),
         reasons=dict(Counter(v.reason for v in real_valid if not v.valid)))
    d_ho, _ = ev.nearest_neighbour(X[ho, :3], M[ho], X[tr, :3], M[tr])
    d_ho_al, _ = ev.nearest_neighbour(X[ho, :3], M[ho], X[tr, :3], M[tr], aligned=True)
    emit(case="nn_baseline", what="held-out real -> train", n=len(ho), mean=float(d_ho.mean()),
         median=float(np.median(d_ho)), min=float(d_ho.min()), aligned_mean=float(d_ho_al.mean()),
         aligned_min=float(d_ho_al.min()))

    # ---- samples per prompt
    prompts = ([(p, next((c for c in classes if rows and any(r.get("prompt") == p and r["labels"]["expression_name"] == c
                                                             for r in rows)), None)) for p in a.prompts]
               if a.prompts else choose_prompts(rows, tr, classes, 4 if a.quick else 8, a.n_prompts))
    if not prompts:
        raise GeofaceError("no prompt to sample (no expression class with enough training items)")
    rng = np.random.default_rng(a.seed)
    summary = []
    for k, (prompt, cls) in enumerate(prompts):
        t = time.perf_counter()
        x = sample(drun, prompt, n=a.samples_per_prompt, steps=a.sample_steps, guidance=a.guidance,
                   seed=a.seed + k, device=a.device, quiet=True, clip=a.clip if a.clip > 0 else None)
        secs = time.perf_counter() - t
        gis = to_geometry_images(x, state)
        S, SM = as_model_space(gis)
        val = [ev.mesh_validity(g) for g in gis]
        pred = ev.predict(clf, S)
        acc = float(np.mean(pred == classes.index(cls))) if cls is not None else None
        same = np.flatnonzero(labels == cls) if cls is not None else np.arange(len(rows))
        ref = rng.choice(same, size=min(len(same), len(S)), replace=False)
        v_s = ev.vendi_score(ev.cosine_similarity(features(S, mean)))
        v_r = ev.vendi_score(ev.cosine_similarity(features(X[ref], mean)))
        d, j = ev.nearest_neighbour(S[:, :3], SM, X[tr, :3], M[tr])
        d_al, j = ev.nearest_neighbour(S[:, :3], SM, X[tr, :3], M[tr], aligned=True)
        rec = dict(case="prompt", prompt=prompt, expression=cls, n=len(S), sample_seconds=secs,
                   valid_rate=float(np.mean([v.valid for v in val])),
                   invalid_reasons=dict(Counter(v.reason for v in val if not v.valid)),
                   text_accuracy=acc, chance=1.0 / len(classes), predicted=dict(Counter(classes[p] for p in pred)),
                   vendi_samples=v_s, vendi_real=v_r, vendi_real_n=len(ref),
                   nn_mean=float(d.mean()), nn_min=float(d.min()), nn_aligned_mean=float(d_al.mean()),
                   nn_aligned_min=float(d_al.min()), nn_train_items=sorted({rows[tr[i]]["item"] for i in j}))
        emit(**rec)
        summary.append(rec)
        montage(a.out / f"samples_{k}_{(cls or 'prompt')}.png", S)
    montage(a.out / "real_reference.png", X[[int(np.flatnonzero(labels == c)[0]) for (_, c) in prompts if c is not None]])
    allv = [r["valid_rate"] for r in summary]
    emit(case="summary", prompts=len(summary), samples=sum(r["n"] for r in summary), valid_rate=float(np.mean(allv)),
         text_accuracy_mean=float(np.mean([r["text_accuracy"] for r in summary if r["text_accuracy"] is not None])),
         chance=1.0 / len(classes), vendi_samples_mean=float(np.mean([r["vendi_samples"] for r in summary])),
         vendi_real_mean=float(np.mean([r["vendi_real"] for r in summary])),
         nn_samples_mean=float(np.mean([r["nn_mean"] for r in summary])), nn_held_out_mean=float(d_ho.mean()),
         nn_aligned_samples_mean=float(np.mean([r["nn_aligned_mean"] for r in summary])),
         nn_aligned_held_out_mean=float(d_ho_al.mean()))
    args = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(a).items()}
    (a.out / "results.json").write_text(json.dumps({"args": args, "results": RESULTS}, indent=1), encoding="utf-8")
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
