"""The dataset builder: failures recorded not fatal, resumable, identical bytes on every backend."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from geoface.cli import main
from geoface.dataset import DatasetOptions, build_dataset, load_labels, read_manifest
from geoface.errors import GeofaceError

REPO = Path(__file__).resolve().parents[1]
OPTS = DatasetOptions(res=32, augment=2)


def _tool():
    spec = importlib.util.spec_from_file_location("make_synthetic_heads", REPO / "data_tools" / "make_synthetic_heads.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def heads(tmp_path_factory):
    d = tmp_path_factory.mktemp("heads")
    _tool().make_synthetic_heads(d, count=3, n_vertices=1500, seed=0)
    (d / "zz_corrupt.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\nthis is not a mesh\n")
    return d


@pytest.fixture(scope="module")
def serial(heads, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / "ds"
    return out, build_dataset(heads, out, OPTS, workers=1, quiet=True)


def _files(root: Path) -> dict:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file() and p.name != "manifest.jsonl"}


def test_corrupt_mesh_is_reported_and_the_rest_complete(serial):
    out, s = serial
    assert s["items"] == 8 and s["done"] == 6 and s["failed"] == 2 and s["skipped"] == 0
    assert set(s["failures"]) == {"zz_corrupt/aug0", "zz_corrupt/aug1"}
    rows = read_manifest(out)
    assert len(rows) == 8
    bad = rows["zz_corrupt/aug0"]
    assert bad["status"] == "failed" and "zz_corrupt.obj" in bad["error"]
    for k in range(3):
        for a in range(2):
            row = rows[f"head_{k:04d}/aug{a}"]
            assert row["status"] == "ok" and row["corner_set"] == a
            assert row["metrics"]["distortion"]["flipped"] == 0
            assert 0 < row["metrics"]["roi_pixel_share"] < 1  # the face mask beside the mesh was used
            assert row["prompt"] and row["labels"]["name"] == f"head_{k:04d}"
            folder = out / f"head_{k:04d}" / f"aug{a}"
            assert {"position.png", "normal.png", "texture.png", "mask.png", "meta.json"} <= {p.name for p in folder.iterdir()}
            meta = (folder / "meta.json").read_text()
            assert len(json.loads(meta)["corners"]) == 4 and "seconds" not in meta  # no timings: reproducible bytes
    # different corner sets give different images
    a0 = (out / "head_0000" / "aug0" / "position.png").read_bytes()
    a1 = (out / "head_0000" / "aug1" / "position.png").read_bytes()
    assert a0 != a1


def test_second_run_does_no_work(heads, serial):
    out, _ = serial
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    s = build_dataset(heads, out, OPTS, workers=1, quiet=True)
    assert s["done"] == 0 and s["failed"] == 0 and s["skipped"] == 8
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == before


def test_a_deleted_item_is_rebuilt(heads, serial, tmp_path):
    import shutil

    out = tmp_path / "ds"
    shutil.copytree(serial[0], out)
    shutil.rmtree(out / "head_0001" / "aug1")
    s = build_dataset(heads, out, OPTS, workers=1, quiet=True)
    assert s["done"] == 1 and s["skipped"] == 7
    assert _files(out) == _files(serial[0])


def test_process_pool_gives_identical_bytes(heads, serial, tmp_path):
    s = build_dataset(heads, tmp_path / "ds", OPTS, workers=2, quiet=True)
    assert s["done"] == 6 and s["failed"] == 2
    assert _files(tmp_path / "ds") == _files(serial[0])


def test_dask_local_cluster_gives_identical_bytes(heads, serial, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        s = build_dataset(heads, tmp_path / "ds", OPTS, scheduler=cluster.scheduler_address, quiet=True)
    assert s["done"] == 6 and s["failed"] == 2
    assert _files(tmp_path / "ds") == _files(serial[0])


def test_cli_build_and_errors(heads, tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["dataset", "build", str(heads), "-o", str(out), "--res", "16", "--augment", "1", "--workers", "1", "-q"]) == 0
    text = capsys.readouterr().out
    assert "3 items built, 1 failed" in text and "zz_corrupt/aug0" in text
    assert main(["dataset", "build", str(heads), "-o", str(out), "--res", "16", "--augment", "1", "--workers", "1", "-q", "--strict"]) == 0
    assert main(["dataset", "build", str(heads), "-o", str(out), "--res", "16", "--augment", "1", "--workers", "1", "-q",
                 "--strict", "--retry-failed"]) == 1
    capsys.readouterr()
    assert main(["dataset", "build", str(tmp_path / "missing"), "-o", str(tmp_path / "o"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("geoface: error: input folder not found") and err.count("\n") == 1
    (tmp_path / "empty").mkdir()
    assert main(["dataset", "build", str(tmp_path / "empty"), "-o", str(tmp_path / "o"), "-q"]) == 2
    assert main(["dataset", "build", str(heads), "-o", str(tmp_path / "o"), "--augment", "9", "-q"]) == 2
    assert not (tmp_path / "o").exists()


def test_bad_options_and_labels(heads, tmp_path):
    with pytest.raises(GeofaceError, match="roi"):
        build_dataset(heads, tmp_path / "o", DatasetOptions(roi="eyes"))
    with pytest.raises(GeofaceError, match="workers"):
        build_dataset(heads, tmp_path / "o", OPTS, workers=0)
    bad = tmp_path / "labels.jsonl"
    bad.write_text('{"prompt": "no name"}\n')
    with pytest.raises(GeofaceError, match="name"):
        load_labels(bad)
    bad.write_text("{not json\n")
    with pytest.raises(GeofaceError, match="cannot read"):
        load_labels(bad)


def test_synthetic_labels_are_deterministic_and_match_parameters():
    tool = _tool()
    a = [tool.sample(i, 7) for i in range(40)]
    assert a == [tool.sample(i, 7) for i in range(40)]
    assert a != [tool.sample(i, 8) for i in range(40)]
    seen = set()
    for lab in a:
        p, e, ident = lab["prompt"], lab["expression"], lab["identity"]
        name, w = max(e.items(), key=lambda kv: kv[1])
        seen.add(lab["expression_name"])
        assert lab["expression_name"] == (name if w >= 0.3 else "neutral")
        gender = "male" if ident["masculinity"] > 0.25 else "female" if ident["masculinity"] < -0.25 else "person"
        assert f" {gender}" in p and lab["gender"] == gender
        words = {"smile": "smiling", "frown": "frowning", "pout_left": "to the left", "pout_right": "to the right",
                 "jaw_open": "mouth wide open", "pucker": "puckered", "cheek_puff": "puffed cheeks",
                 "eyes_closed_left": "left eye closed", "eyes_closed_right": "right eye closed", "brow_raise": "surprised"}
        if lab["expression_name"] != "neutral":
            key = words[name]
            if name == "brow_raise" and gender == "person":
                key = "raised eyebrows"
            assert key in p, (p, name)
    assert len(seen) >= 6  # the set covers many expressions
    assert np.mean([lab["expression_name"] == "neutral" for lab in a]) < 0.4


def test_an_option_added_since_a_folder_was_built_counts_as_its_default(tmp_path):
    """A folder built before ``find_face`` existed (its ``options.json`` lacks it) resumes with
    the default, and is refused with the other value."""
    import json

    from geoface.dataset import DatasetOptions, _record_options
    from geoface.errors import GeofaceError

    _record_options(tmp_path, DatasetOptions(res=16), rebuild=False)
    old = json.loads((tmp_path / "options.json").read_text())
    del old["find_face"]
    (tmp_path / "options.json").write_text(json.dumps(old))
    assert _record_options(tmp_path, DatasetOptions(res=16), rebuild=False) is False
    (tmp_path / "options.json").write_text(json.dumps(old))
    with pytest.raises(GeofaceError, match="find_face"):
        _record_options(tmp_path, DatasetOptions(res=16, find_face=False), rebuild=False)


def test_a_build_that_fails_before_any_item_leaves_nothing(heads, tmp_path, monkeypatch):
    """An unreachable scheduler (the executor fails) into a new folder: the folder is gone again;
    a folder whose manifest is binary: refused before its options.json is written."""
    import geoface.dataset as D
    from geoface.errors import GeofaceError

    def unreachable(workers, scheduler):
        raise GeofaceError("cannot connect to the Dask scheduler tcp://127.0.0.1:9")

    monkeypatch.setattr(D, "executor", unreachable)
    with pytest.raises(GeofaceError, match="scheduler"):
        D.build_dataset(heads, tmp_path / "new", D.DatasetOptions(res=16, augment=1), scheduler="tcp://127.0.0.1:9", quiet=True)
    assert not (tmp_path / "new").exists()
    old = tmp_path / "old"
    old.mkdir()
    (old / "manifest.jsonl").write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(GeofaceError, match="not a text file"):
        D.build_dataset(heads, old, D.DatasetOptions(res=16, augment=1), workers=1, quiet=True)
    assert sorted(p.name for p in old.iterdir()) == ["manifest.jsonl"]


def test_a_second_build_into_the_same_folder_is_refused_while_the_first_runs(heads, tmp_path):
    """Two builds into one folder once both exited 0 with every manifest row twice: the folder is
    locked for a build (flock on the folder), so while one holds it another is one line; after it,
    the build runs."""
    import os

    import geoface.dataset as D

    out = tmp_path / "ds"
    out.mkdir()
    held = D._lock_folder(out)  # as a running build holds it
    try:
        with pytest.raises(GeofaceError, match="another dataset build is writing into"):
            build_dataset(heads, out, DatasetOptions(res=16, augment=1, find_face=False), workers=1, quiet=True)
    finally:
        os.close(held)
    assert build_dataset(heads, out, DatasetOptions(res=16, augment=1, find_face=False), workers=1, quiet=True)["done"] > 0
