"""DDPM variants side by side at equal training steps, on a machine that lacks the geometry stack.

A GPU machine often has torch but not the text encoder's weights or the mesh libraries.  This
script splits the work:

``pack`` (here) reads the training split of a ``geoface dataset ict`` output at one resolution in
the dataset frame (:class:`geoface.ddpm.data.GImageDataset`, as ``ddpm train`` sees it), embeds
its prompts and the preset prompts with the run's text encoder, and writes one compressed file
(residuals from the mean image quantised, :data:`STEPS`; token embeddings in float16).

``train`` (there) trains each ``--variant`` on the pack with :func:`geoface.ddpm.model.train`
(same loop, same losses), then draws ``--samples-per-prompt`` samples for each preset prompt and
writes them with the run's state (``OUT/<variant>.npz``) and one JSON line per variant (steps,
steps/s, seconds).

``judge`` (here) decodes the samples in the run's frame and checks each as
``bench/eval_ddpm.py`` does (a clean manifold disk: one component, one boundary loop, no
degenerate, folded or self-intersecting face; the coverage mask completed by the data's support).

    python bench/ddpm_sweep.py pack --data ict64/ --res 64 -o .gpu/pack64.npz
    python bench/ddpm_sweep.py train --pack .gpu/pack64.npz --out OUT --device cuda \\
        --variant p1:patch=1:steps=5200 --variant p2:patch=2:steps=16000
    python bench/ddpm_sweep.py judge --pack .gpu/pack64.npz --samples OUT/ -o results.jsonl

A variant is ``NAME:key=value:...`` with keys ``steps`` and any :class:`DDPMConfig` field
(``patch``, ``prediction``, ``schedule_shift``, ``lr``, ``batch_size``, ...).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

# quantisation steps of the packed residuals (image - mean image) per modality, in the dataset
# frame (about [-1, 1]): positions to 2^-12 of the frame's half-width, normals to 2^-10
STEPS = {"position": 2.0 ** -12, "normal": 2.0 ** -10}


def _encode(X: np.ndarray) -> dict:
    """``X [n, 6, R, R]`` → mean image + per-modality residuals quantised to int16, each byte plane
    lzma-compressed (the high bytes are nearly constant)."""
    import lzma
    mean = X.mean(0).astype(np.float32)
    out = {"mean": mean, "shape": np.array(X.shape)}
    for k, (m, step) in enumerate(STEPS.items()):
        r = np.round((X[:, 3 * k:3 * k + 3] - mean[3 * k:3 * k + 3]) / step).astype("<i2")
        b = r.view(np.uint8).reshape(r.shape + (2,))
        for plane in (0, 1):
            out[f"{m}_{plane}"] = np.frombuffer(lzma.compress(np.ascontiguousarray(b[..., plane]).tobytes(), preset=9), np.uint8)
    return out


def _decode(z) -> np.ndarray:
    import lzma
    n, C, R, _ = (int(v) for v in z["shape"])
    X = np.empty((n, C, R, R), np.float32)
    for k, (m, step) in enumerate(STEPS.items()):
        b = np.stack([np.frombuffer(lzma.decompress(z[f"{m}_{p}"].tobytes()), np.uint8) for p in (0, 1)], -1)
        r = b.reshape(-1).view("<i2").reshape(n, 3, R, R)
        X[:, 3 * k:3 * k + 3] = r * step + z["mean"][3 * k:3 * k + 3]
    return X


def emit(out, **d):
    line = json.dumps({k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in d.items()})
    print(line, flush=True)
    if out is not None:
        with open(out, "a", encoding="utf-8") as f:
            f.write(line + "\n")


# ---------------------------------------------------------------- pack (here)
def _eval_module():
    import importlib.util
    spec = importlib.util.spec_from_file_location("eval_ddpm", REPO / "bench" / "eval_ddpm.py")
    ev = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ev)
    return ev


def pack(a) -> None:
    import tempfile

    import torch

    from geoface.ddpm.data import GImageDataset
    from geoface.ddpm.text import make_text_encoder
    from geoface.synth.ict_data import PRESET_PROMPTS

    ev = _eval_module()
    rows = ev.read_items(a.data)
    train_idx = [k for k, r in enumerate(rows) if (r["labels"].get("split") or "train") == "train"]
    with tempfile.TemporaryDirectory() as tmp:  # the training split, framed as eval_ddpm frames it
        ds = GImageDataset(ev.write_split(a.data, rows, train_idx, Path(tmp) / "train"), res=a.res,
                           modalities=("position", "normal"), cache_mb=0)
        X = np.stack([ds[k]["image"].numpy() for k in range(len(ds))])
        stats = ds.bbox_stats()
    keep = range(len(ds))
    prompts = [ds.items[k].prompt for k in keep]
    text = make_text_encoder(a.text, max_length=32)
    vocab = sorted(set(prompts) | set(PRESET_PROMPTS.values()) | {""})
    emb = text.embed(vocab)
    lengths = emb.mask.sum(1).numpy().astype(np.int32)
    # the real tokens only, one after another (the padding is zero)
    assert float(emb.tokens[~emb.mask].abs().max()) == 0.0 if (~emb.mask).any() else True
    tokens = torch.cat([emb.tokens[k, :n] for k, n in enumerate(lengths)]).to(torch.float16).numpy()
    np.savez(a.out, **_encode(X), prompt_index=np.array([vocab.index(p) for p in prompts], np.int32),
                        vocab=np.array(vocab), tokens=tokens, lengths=lengths,
                        meta=np.array(json.dumps({"res": a.res, "text": a.text, "text_dim": int(text.dim),
                                                  "max_length": 32, "modalities": ["position", "normal"],
                                                  "state": stats, "presets": PRESET_PROMPTS,
                                                  "items": len(keep)})))
    print(json.dumps({"case": "pack", "items": len(keep), "prompts": len(vocab), "bytes": a.out.stat().st_size}))


class PackedData:
    """The pack as the training loop's dataset (see ``geoface.ddpm.model.train(dataset=)``)."""

    def __init__(self, z):
        meta = json.loads(str(z["meta"]))
        self.images = _decode(z)
        self.vocab = [str(v) for v in z["vocab"]]
        self.prompts = [self.vocab[i] for i in z["prompt_index"]]
        self.modalities = tuple(meta["modalities"])
        self.channels = 3 * len(self.modalities)
        self.augment = False
        self._state = meta["state"]

    def __len__(self):
        return len(self.images)

    def __getitem__(self, key):
        import torch
        i = int(key[0] if isinstance(key, tuple) else key)
        x = torch.from_numpy(self.images[i])
        return {"image": x, "mask": (x[3:6].norm(dim=0) > 0.5).float()[None], "prompt": self.prompts[i], "index": i}

    def bbox_stats(self):
        return dict(self._state)


class PackedText:
    """Token embeddings of the pack's prompts (the encoder itself is not needed)."""

    def __init__(self, z):
        import torch
        meta = json.loads(str(z["meta"]))
        self.name, self.dim, self.max_length = meta["text"], int(meta["text_dim"]), int(meta["max_length"])
        tok = torch.from_numpy(z["tokens"].astype(np.float32))
        ends = np.cumsum(z["lengths"])
        self.table = {}
        for k, v in enumerate(z["vocab"]):
            full = torch.zeros(self.max_length, self.dim)
            n = int(z["lengths"][k])
            full[:n] = tok[ends[k] - n:ends[k]]
            self.table[str(v)] = full

    def encode(self, prompts):
        import torch
        try:
            return torch.stack([self.table[p] for p in prompts])
        except KeyError as e:
            raise SystemExit(f"prompt {e} is not in the pack") from None


def parse_variant(s: str) -> tuple[str, dict]:
    name, *kv = s.split(":")
    out = {}
    for item in kv:
        k, v = item.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return name, out


# ---------------------------------------------------------------- train (there)
def train_variants(a) -> None:
    import torch

    from geoface.ddpm.model import DDPMConfig, build_unet, load_run, sample

    z = np.load(a.pack)
    meta = json.loads(str(z["meta"]))
    data, text = PackedData(z), PackedText(z)
    a.out.mkdir(parents=True, exist_ok=True)
    log = a.out / "sweep.jsonl"
    for spec in a.variant:
        name, kw = parse_variant(spec)
        steps = int(kw.pop("steps", 5000))
        cfg = DDPMConfig.preset(kw.pop("model", "small"), res=int(meta["res"]), text_encoder=meta["text"], steps=steps,
                                checkpoint_every=max(steps, 1), augment=False, seed=a.seed, **kw)
        run = a.out / f"run_{name}"
        t = time.perf_counter()
        last = train(None, run, cfg, device=a.device, quiet=True, text_encoder=text, dataset=data,
                     max_seconds=a.max_minutes * 60 if a.max_minutes else None)
        secs = time.perf_counter() - t
        drun = load_run(run, text_encoder=text)
        t = time.perf_counter()
        samples, prompts = [], []
        for k, (cls, prompt) in enumerate(meta["presets"].items()):
            x = sample(drun, prompt, n=a.samples_per_prompt, steps=a.sample_steps, guidance=a.guidance, seed=a.seed + k,
                       device=a.device, quiet=True)
            samples.append(x.numpy().astype(np.float16))
            prompts += [cls] * len(x)
        np.savez_compressed(a.out / f"{name}.npz", samples=np.concatenate(samples), expression=np.array(prompts),
                            state=np.array(json.dumps(drun.state)), config=np.array(drun.config.to_json()))
        emit(log, case="variant", name=name, steps=last["step"], seconds=secs, steps_per_second=last["step"] / secs,
             loss=last["loss"], sample_seconds=time.perf_counter() - t, device=a.device,
             params=sum(p.numel() for p in build_unet(drun.config).parameters()), **{k: v for k, v in kw.items()})


def train(*args, **kw):
    from geoface.ddpm.model import train as _train
    return _train(*args, **kw)


# ---------------------------------------------------------------- judge (here)
def judge(a) -> None:
    ev = _eval_module()
    z = np.load(a.pack)
    ref = z["mean"][:3].reshape(3, -1).T
    files = sorted(a.samples.glob("*.npz")) if a.samples.is_dir() else [a.samples]
    for f in files:
        s = np.load(f)
        state = json.loads(str(s["state"]))
        S = s["samples"].astype(np.float32)
        J = ev.Judge(state, ref, a.render_size, ["front"])
        J.support = np.ones(S.shape[-2:], bool)  # every ICT head covers the whole square
        _, val = J(S)
        val_s = J.support_validity(S)
        from collections import Counter
        emit(a.o, case="judge", name=f.stem, n=len(S), valid_rate=float(np.mean([v.valid for v in val])),
             valid_rate_support=float(np.mean([v.valid for v in val_s])),
             median_folded=float(np.median([max(v.folded_faces, 0) / max(v.faces, 1) for v in val_s])),
             median_self_intersecting=float(np.median([max(v.self_intersecting_faces, 0) / max(v.faces, 1) for v in val_s])),
             reasons_support=dict(Counter(v.reason for v in val_s if not v.valid)),
             config={k: json.loads(str(s["config"])).get(k) for k in ("res", "patch", "prediction", "schedule_shift",
                                                                       "stats_per_pixel", "ema_decay", "lr_schedule")},
             step=state.get("step"))
        J.renderer.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("pack")
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--text", default="minilm")
    p.add_argument("-o", "--out", type=Path, required=True)
    t = sub.add_parser("train")
    t.add_argument("--pack", type=Path, required=True)
    t.add_argument("--variant", action="append", required=True)
    t.add_argument("--out", type=Path, required=True)
    t.add_argument("--device", default="cuda")
    t.add_argument("--samples-per-prompt", type=int, default=8)
    t.add_argument("--sample-steps", type=int, default=50)
    t.add_argument("--guidance", type=float, default=3.0)
    t.add_argument("--max-minutes", type=float, default=None, help="wall-clock cap per variant")
    t.add_argument("--seed", type=int, default=0)
    j = sub.add_parser("judge")
    j.add_argument("--pack", type=Path, required=True)
    j.add_argument("--samples", type=Path, required=True, help="a variant's .npz or a folder of them")
    j.add_argument("--render-size", type=int, default=64)
    j.add_argument("-o", type=Path, default=None, help="append the JSON lines here")
    a = ap.parse_args()
    {"pack": pack, "train": train_variants, "judge": judge}[a.cmd](a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
