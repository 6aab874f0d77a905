"""``geoface convert`` from 10K to 2M vertices: seconds per stage, peak memory, accuracy, and the
log-log slope of time against size.  One JSON line per mesh and setting; each conversion runs in
a fresh process, so its peak resident memory is its own.

The meshes are the Max Planck bust Loop-subdivided, decimated to the size and displaced by scan
noise (``data_tools/make_dense_head.py``), written once as binary PLY into ``--cache``.  Every
conversion is one corner set at ``--res`` with the defaults (meshes above 45K vertices through the
30K-vertex proxy), reconstruction and error report included; ``--no-proxy`` sizes are also run with
``--proxy 0`` (the whole scan through every stage) to compare at equal settings.

    python bench/bench_scale.py [--sizes 10000 50000 200000 500000 1000000 2000000] [--no-proxy 200000]
        [--files bust134k.obj] [--res 512] [--cache /tmp/geoface_scale] [--scan] [--source max|ict0]
        [--proxies 10000 15000 20000 30000] [--repeat 3] [--out bench/results/convert/scale_512.jsonl]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from geoface.pipeline import DEFAULT_PROXY  # noqa: E402

CHILD = r"""
import json, resource, sys, time
t = time.perf_counter()
from geoface.mesh.io import load_mesh
from geoface.pipeline import ConvertOptions, convert
mesh = load_mesh(sys.argv[1])
load = time.perf_counter() - t
m = convert(mesh, sys.argv[2], ConvertOptions(res=int(sys.argv[3]), proxy=int(sys.argv[4])), quiet=True)
total = time.perf_counter() - t
st = m["sets"][0]
out = {"vertices": len(mesh.V), "faces": len(mesh.F), "proxy_vertices": m.get("proxy", {}).get("proxy_vertices"),
       "seconds": {"load": load, "proxy": m["seconds"].get("proxy", 0.0), "repair": m["seconds"]["repair"],
                   "full_surface": m["seconds"].get("full_surface", 0.0), "ricci": st["ricci"]["seconds"],
                   "ot": st["ot"]["seconds"], "images": st["images_seconds"],
                   "reconstruction": st["reconstruction"]["seconds"], "total": total},
       "ot_iterations": st["ot"]["iterations"], "flipped": st["distortion"]["flipped"],
       "hausdorff": st["reconstruction"]["hausdorff"], "face_hausdorff": st["reconstruction"].get("face_hausdorff"),
       "mean_distance": st["reconstruction"]["mean"], "face_mean_distance": st["reconstruction"].get("face_mean"),
       "roi_pixel_share": st.get("roi_pixel_share"),
       "qc_p95": st["distortion"]["qc_p95"], "log_area_abs_p95": st["distortion"]["log_area_abs_p95"],
       "face_pixels": st.get("face_pixels"), "level": (m.get("face") or {}).get("level"),
       "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
print(json.dumps(out))
"""


def mesh_file(cache: Path, n: int, scan: bool = False, source: str = "max") -> Path:
    f = cache / f"{source}_{n}{'_scan' if scan else ''}.ply"
    if not f.is_file():
        cache.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, str(REPO / "data_tools" / "make_dense_head.py"), str(f), "--vertices", str(n),
                        "--source", source] + (["--scan"] if scan else []), check=True, stdout=subprocess.DEVNULL)
    return f


def run(file: Path, res: int, proxy: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        p = subprocess.run([sys.executable, "-c", CHILD, str(file), str(Path(tmp) / "out"), str(res), str(proxy)],
                           capture_output=True, text=True, cwd=REPO, env={**os.environ, "GEOFACE_QUIET": "1"})
    if p.returncode:
        return {"error": p.stderr.strip().splitlines()[-1] if p.stderr.strip() else f"exit {p.returncode}"}
    return json.loads(p.stdout.strip().splitlines()[-1])


def calibration() -> dict:
    """How fast this machine is as the bench starts (a shared machine's speed drifts by a third
    between hours): a pure-Python loop of 3M additions and a 2000² float64 matrix product, each
    the best of three, in a fresh process. The quiet 2-core machine: about 0.08 s and 0.16 s."""
    code = ("import time, numpy as np\n"
            "def best(f):\n    r = []\n    for _ in range(3):\n        t = time.perf_counter(); f(); r.append(time.perf_counter() - t)\n    return min(r)\n"
            "def loop():\n    s = 0\n    for i in range(3000000): s += i\n"
            "a = np.random.default_rng(0).random((2000, 2000))\n"
            "print(best(loop), best(lambda: a @ a))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    return {"case": "calibration", "python_loop_s": round(float(out[0]), 3), "matmul_2000_s": round(float(out[1]), 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="*", type=int, default=[10000, 50000, 200000, 500000, 1000000, 2000000])
    ap.add_argument("--no-proxy", nargs="*", type=int, default=[200000], help="sizes also run with --proxy 0")
    ap.add_argument("--proxies", nargs="*", type=int, default=[DEFAULT_PROXY],
                    help="proxy sizes each size is run with (a sweep: accuracy against time)")
    ap.add_argument("--source", default="max", help="make_dense_head.py's --source (max: the bust; ict0: an ICT head)")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--repeat", type=int, default=1, help="runs of each --files mesh (each in a fresh process)")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "geoface_scale")
    ap.add_argument("--out", type=Path, default=None, help="also append the JSON lines to this file")
    ap.add_argument("--label", default=None, help="written into the calibration line as its 'code' (which code, which batch)")
    ap.add_argument("--scan", action="store_true",
                    help="scan-like meshes (make_dense_head.py --scan: holes, a ragged rim, debris, uneven triangles)")
    ap.add_argument("--files", nargs="*", type=Path, default=[],
                    help="more meshes to time with the defaults, outside the slope (e.g. the 134K bust of "
                         "data_tools/make_dense_bust.py)")
    args = ap.parse_args()

    def emit(row: dict) -> None:
        line = json.dumps(row)
        print(line, flush=True)
        if args.out:
            with open(args.out, "a") as fh:
                fh.write(line + "\n")

    emit({**calibration(), **({"code": args.label} if args.label else {})})
    rows = []
    jobs = [(n, p) for n in args.sizes for p in args.proxies] + [(n, 0) for n in args.no_proxy]
    for n, proxy in jobs:
        r = {"case": "scale", "target_vertices": n, "res": args.res, "proxy": proxy, "scan_like": args.scan,
             **({"source": args.source} if args.source != "max" else {}),
             **run(mesh_file(args.cache, n, args.scan, args.source), args.res, proxy)}
        rows.append(r)
        emit(r)
    for f in args.files:
        for proxy in args.proxies:
            for k in range(args.repeat):
                emit({"case": "scale_file", "mesh": f.name, "res": args.res, "proxy": proxy,
                      **({"run": k} if args.repeat > 1 else {}), **run(f, args.res, proxy)})
    ok = [r for r in rows if r["proxy"] == DEFAULT_PROXY and "error" not in r]
    if len(ok) >= 2:
        x = np.log([r["vertices"] for r in ok])
        for key in ("total", "total_without_report"):
            y = np.log([r["seconds"]["total"] - (r["seconds"]["reconstruction"] if key != "total" else 0.0) for r in ok])
            slope = float(np.polyfit(x, y, 1)[0])
            emit({"case": "scale_slope", "of": key, "sizes": [r["vertices"] for r in ok], "loglog_slope": slope})


if __name__ == "__main__":
    main()
