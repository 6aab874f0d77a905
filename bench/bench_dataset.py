"""Dataset-builder throughput; one JSON line per run.

Makes ``--count`` labelled synthetic heads (``data_tools/make_synthetic_heads.py``) plus one
corrupt file, then builds them at ``--res`` with ``--augment`` corner sets:

* with 1 worker and with 2 workers (items per minute; the corrupt file must be the only failure),
* a second run over the 2-worker output (must do no work),
* a Dask run on a local cluster of 2 worker processes, compared byte for byte with the others.

    python bench/bench_dataset.py [--count 100] [--vertices 3000] [--res 128] [--augment 1]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def emit(**d):
    print(json.dumps({k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in d.items()}), flush=True)


def files(root: Path) -> dict:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file() and p.name != "manifest.jsonl"}


def main() -> None:
    from geoface.dataset import DatasetOptions, build_dataset

    ap = argparse.ArgumentParser()
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--vertices", type=int, default=3000)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--augment", type=int, default=1)
    ap.add_argument("--no-dask", action="store_true")
    a = ap.parse_args()
    spec = importlib.util.spec_from_file_location("make_synthetic_heads", REPO / "data_tools" / "make_synthetic_heads.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    opts = DatasetOptions(res=a.res, augment=a.augment)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        tool.make_synthetic_heads(tmp / "in", count=a.count, n_vertices=a.vertices, seed=0)
        (tmp / "in" / "corrupt_scan.obj").write_bytes(b"v 0 0 0\nf 1 2 3\n\x00\x01garbage")
        emit(case="synthetic_heads", count=a.count, vertices=a.vertices, seconds=time.perf_counter() - t)
        outs = {}
        for workers in (1, 2):
            out = tmp / f"out{workers}"
            s = build_dataset(tmp / "in", out, opts, workers=workers, quiet=True)
            outs[workers] = out
            emit(case="build", workers=workers, items=s["items"], done=s["done"], failed=s["failed"],
                 failures=sorted(s["failures"]), seconds=s["seconds"], items_per_minute=s["items_per_minute"],
                 res=a.res, augment=a.augment, vertices=a.vertices)
        s = build_dataset(tmp / "in", outs[2], opts, workers=2, quiet=True)
        emit(case="rerun", workers=2, done=s["done"], failed=s["failed"], skipped=s["skipped"], seconds=s["seconds"])
        same = files(outs[1]) == files(outs[2])
        emit(case="identical", a="workers=1", b="workers=2", identical=same)
        if not a.no_dask:
            from dask.distributed import LocalCluster

            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
                s = build_dataset(tmp / "in", tmp / "dask", opts, scheduler=cluster.scheduler_address, quiet=True)
            emit(case="build", scheduler="dask LocalCluster(2 processes)", items=s["items"], done=s["done"], failed=s["failed"],
                 seconds=s["seconds"], items_per_minute=s["items_per_minute"])
            emit(case="identical", a="workers=1", b="dask", identical=files(outs[1]) == files(tmp / "dask"))


if __name__ == "__main__":
    main()
