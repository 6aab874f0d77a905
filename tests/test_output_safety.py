"""Nothing a user owns is lost: companion files named after their mesh, one output-path
policy (--force to replace), the user's umask, leftovers cleaned, SIGTERM like SIGINT, and
bad values as one line with exit code 2."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from geoface.mesh.io import Mesh, load_mesh, save_mesh
from tests.helpers import geoface


def run(*args, cwd=None, umask=None):
    """The console command: in this process (``tests.helpers.geoface``), or in a real one under
    ``umask`` (a process's own setting, which a test here must not change for the others)."""
    if umask is None:
        return geoface(*args, cwd=cwd)
    p = subprocess.run([sys.executable, "-m", "geoface", "--quiet", *map(str, args)], capture_output=True, text=True,
                       cwd=cwd, preexec_fn=lambda: os.umask(umask))
    return p.returncode, p.stdout, p.stderr


def digest(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def one_line_error(code, err):
    return code == 2 and err.startswith("geoface") and ": error: " in err and len(err.strip().splitlines()) == 1


# converts whose subject is the files, not the frame, pass --no-find-face (2-3 s less each)

@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The `make demo` sequence in a temporary folder: head, convert, reconstruct."""
    d = tmp_path_factory.mktemp("demo")
    assert run("synth", "head", "-o", d / "head.obj", "--vertices", "3000", "--seed", "0", "--meta", d / "head.json")[0] == 0
    before = digest(d)
    assert run("convert", d / "head.obj", "-o", d / "head_gim", "--res", "64", "--roi", d / "head.json")[0] == 0
    code, _, err = run("reconstruct", d / "head_gim", "-o", d / "head_reconstructed.obj")
    assert code == 0, err
    return d, before


def test_demo_sequence_keeps_the_head_texture(demo):
    d, before = demo
    after = digest(d)
    for name, h in before.items():  # head.obj, head.mtl, head.png, head.json: untouched
        assert after[name] == h, name
    # each mesh has its own companions, named after it
    assert (d / "head_texture.png").is_file() and (d / "head_reconstructed_texture.png").is_file()
    assert (d / "head_reconstructed_normal.png").is_file() and not (d / "material_0.png").exists()
    assert "map_Kd head_texture.png" in (d / "head.mtl").read_text()
    assert "map_Kd head_reconstructed_texture.png" in (d / "head_reconstructed.mtl").read_text()
    m = load_mesh(d / "head.obj")
    assert m.texture is not None and m.texture.shape[0] >= 256  # the head's own texture, not a 2x2 placeholder


def test_param_writes_its_own_texture_name(demo, tmp_path):
    d, _ = demo
    h = digest(d)
    code, _, err = run("param", d / "head.obj", "-o", tmp_path / "head_uv.obj")
    assert code == 0, err
    assert digest(d) == h


def test_existing_outputs_need_force(demo, tmp_path):
    d, _ = demo
    out = tmp_path / "mydata"
    out.mkdir()
    (out / "precious.txt").write_text("mine")
    code, _, err = run("convert", d / "head.obj", "-o", out, "--res", "16", "--no-find-face")
    assert one_line_error(code, err) and "--force" in err
    assert (out / "precious.txt").read_text() == "mine"
    # an empty folder is not "existing data"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert run("convert", d / "head.obj", "-o", empty, "--res", "16", "--no-find-face")[0] == 0
    # --force replaces, atomically
    code, _, err = run("convert", d / "head.obj", "-o", out, "--res", "16", "--no-find-face", "--force")
    assert code == 0, err
    assert not (out / "precious.txt").exists() and (out / "meta.json").is_file()
    # a mesh output and its companions
    mesh_out = tmp_path / "disk.obj"
    assert run("repair", d / "head.obj", "-o", mesh_out)[0] == 0
    h = digest(tmp_path)
    code, _, err = run("repair", d / "head.obj", "-o", mesh_out)
    assert one_line_error(code, err) and digest(tmp_path) == h
    (tmp_path / "x_texture.png").write_bytes(b"a user's picture")
    code, _, err = run("synth", "head", "-o", tmp_path / "x.obj", "--vertices", "1000")  # x.obj's texture
    assert one_line_error(code, err) and "x_texture.png" in err
    assert (tmp_path / "x_texture.png").read_bytes() == b"a user's picture"
    # a screenshot may not replace the texture of the mesh it shows, even with --force
    code, _, err = run("view", d / "head.obj", "--screenshot", d / "head_texture.png", "--force")
    assert one_line_error(code, err)


@pytest.mark.parametrize("case", ["json_is_input", "meta_is_output", "screenshot_in_input_folder", "output_in_input_folder",
                                  "same_output_twice"])
def test_an_output_may_not_be_an_input(demo, tmp_path, case):
    d, _ = demo
    h = digest(d)
    args = {
        "json_is_input": ("param", d / "head.obj", "-o", tmp_path / "u.obj", "--json", d / "head.obj"),
        "meta_is_output": ("synth", "head", "-o", tmp_path / "o.obj", "--meta", tmp_path / "o.obj", "--vertices", "1000"),
        "screenshot_in_input_folder": ("view", d / "head_gim", "--screenshot", d / "head_gim" / "position.png"),
        "output_in_input_folder": ("reconstruct", d / "head_gim", "-o", d / "head_gim" / "rec.obj"),
        "same_output_twice": ("param", d / "head.obj", "-o", tmp_path / "u.obj", "--json", tmp_path / "u.mtl"),
    }[case]
    code, _, err = run(*args)
    assert one_line_error(code, err), err
    assert digest(d) == h
    assert not (tmp_path / "o.obj").exists() and not (tmp_path / "u.obj").exists()


def test_outputs_get_the_users_umask(demo, tmp_path):
    d, _ = demo
    code, _, err = run("convert", d / "head.obj", "-o", tmp_path / "out", "--res", "16", "--no-find-face", "--augment", "2", umask=0o022)
    assert code == 0, err
    assert run("reconstruct", tmp_path / "out" / "aug0", "-o", tmp_path / "rec.obj", umask=0o022)[0] == 0
    assert run("synth", "head", "-o", tmp_path / "h.obj", "--vertices", "1000", "--meta", tmp_path / "h.json", umask=0o022)[0] == 0
    for p in [tmp_path / "out", tmp_path / "out" / "aug0"]:
        assert p.stat().st_mode & 0o777 == 0o755, p
    files = [*(tmp_path / "out").rglob("*.*"), *tmp_path.glob("rec*"), *tmp_path.glob("h.*")]
    assert len(files) > 10
    for p in files:
        if p.is_file():
            assert p.stat().st_mode & 0o777 == 0o644, p
    code, _, err = run("synth", "head", "-o", tmp_path / "g.obj", "--vertices", "1000", umask=0o077)
    assert (tmp_path / "g.obj").stat().st_mode & 0o777 == 0o600


def test_tiny_and_huge_coordinates(tmp_path):
    from geoface.synth import procedural_head

    h = procedural_head(n_vertices=1000, seed=0)
    small = Mesh(h.V * 1e-9, h.F)
    save_mesh(tmp_path / "tiny.obj", small)
    back = load_mesh(tmp_path / "tiny.obj")
    assert np.abs(back.V - small.V).max() <= 1e-8 * np.abs(small.V).max()  # not all zeros
    code, _, err = run("inspect", tmp_path / "tiny.obj")
    assert code == 0, err
    big = tmp_path / "big.obj"
    big.write_text("v 1e300 0 0\nv 0 1e300 0\nv 0 0 1e300\nf 1 2 3\n")
    for verb in (("inspect", big), ("repair", big, "-o", tmp_path / "r.obj"), ("convert", big, "-o", tmp_path / "c")):
        code, _, err = run(*verb)
        assert one_line_error(code, err) and "rescale" in err, err
    zero = tmp_path / "zero.obj"
    zero.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n")
    code, _, err = run("inspect", zero)
    assert one_line_error(code, err) and "start at 1" in err


def test_bounds_on_work(tmp_path):
    code, _, err = run("synth", "surface", "sphere", "-o", tmp_path / "s.obj", "--resolution", "1000000000")
    assert one_line_error(code, err) and "resolution" in err
    code, _, err = run("synth", "head", "-o", tmp_path / "h.obj", "--vertices", "1000")
    code, _, err = run("convert", tmp_path / "h.obj", "-o", tmp_path / "c", "--res", "16", "--smooth", "1000000000")
    assert one_line_error(code, err) and "smooth" in err and not (tmp_path / "c").exists()


def test_dataset_rerun_with_other_options_is_refused(tmp_path):
    heads = tmp_path / "heads"
    heads.mkdir()
    for s in range(2):
        assert run("synth", "head", "-o", heads / f"h{s}.obj", "--vertices", "1000", "--seed", s)[0] == 0
    out = tmp_path / "ds"
    code, _, err = run("dataset", "build", heads, "-o", out, "--res", "16", "--no-find-face", "--augment", "1", "--workers", "1")
    assert code == 0, err
    h = digest(out)
    code, _, err = run("dataset", "build", heads, "-o", out, "--res", "32", "--no-find-face", "--augment", "1", "--workers", "1")
    assert one_line_error(code, err) and "res 16 -> 32" in err
    assert digest(out) == h
    # more corner sets with the same options resume (the first items are kept)
    code, out_text, err = run("dataset", "build", heads, "-o", out, "--res", "16", "--no-find-face", "--augment", "2", "--workers", "1")
    assert code == 0 and "2 items built" in out_text, (out_text, err)
    code, out_text, err = run("dataset", "build", heads, "-o", out, "--res", "32", "--no-find-face", "--augment", "1", "--workers", "1", "--force")
    assert code == 0 and "2 items built" in out_text, (out_text, err)
    from geoface.gimage import load_gimage

    assert load_gimage(out / "h0" / "aug0").resolution == 32
    assert json.loads((out / "options.json").read_text())["res"] == 32


def _big_head(tmp_path) -> Path:
    p = tmp_path / "big.obj"
    assert run("synth", "head", "-o", p, "--vertices", "60000")[0] == 0
    return p


def _our_processes(marker: str) -> list[int]:
    out = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return [int(line.split()[0]) for line in out.splitlines()[1:] if marker in line and "ps -eo" not in line]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_killed_convert_leaves_nothing_behind(tmp_path, sig):
    src = _big_head(tmp_path)
    out = tmp_path / "killed_out"
    p = subprocess.Popen([sys.executable, "-m", "geoface", "--quiet", "convert", str(src), "-o", str(out), "--res", "512"])
    time.sleep(4.0)  # inside the pipeline by now
    p.send_signal(sig)
    # a native call in progress (a decimation, an AABB tree) finishes before Python sees the
    # signal: seconds on a loaded 2-core machine
    p.wait(timeout=20)
    assert p.returncode == (143 if sig == signal.SIGTERM else -9)
    leftovers = [x for x in tmp_path.iterdir() if x.name.startswith(".killed_out")]
    if sig == signal.SIGTERM:
        assert leftovers == [] and not out.exists()
    # after SIGKILL a temporary may remain; the next run of the same output removes it (a small head: quick)
    small = tmp_path / "small.obj"
    assert run("synth", "head", "-o", small, "--vertices", "2000")[0] == 0
    code, _, err = run("convert", small, "-o", out, "--res", "16", "--no-find-face")
    assert code == 0, err
    assert [x for x in tmp_path.iterdir() if x.name.startswith(".killed_out")] == []


def _parent(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().split()[3])
    except (OSError, ValueError, IndexError):
        return -1


@pytest.mark.parametrize("case", ["texture_train_into_its_data", "ddpm_train_over_a_run", "hmd_eval_json_in_model",
                                  "talk_eval_json_in_model", "splat_fit_over_input", "ddpm_sample_over_folder"])
def test_neural_commands_keep_what_exists(tmp_path, case):
    """The neural commands follow the same output policy, before any heavy import."""
    data = tmp_path / "data"
    data.mkdir()
    (data / "sample_000.npz").write_bytes(b"a training sample")
    model = tmp_path / "model"
    model.mkdir()
    (model / "config.json").write_text('{"format": "x"}')
    (model / "model.safetensors").write_bytes(b"weights")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "checkpoint").mkdir()
    (run_dir / "checkpoint" / "state.json").write_text("{}")
    cloud = tmp_path / "chead.ply"
    cloud.write_bytes(b"ply\n")
    args = {
        "texture_train_into_its_data": ("texture", "train", data, "-o", data),
        "ddpm_train_over_a_run": ("ddpm", "train", data, "-o", run_dir),
        "hmd_eval_json_in_model": ("hmd", "eval", model, data, "--json", model / "config.json"),
        "talk_eval_json_in_model": ("talk", "eval", model, data, "--json", model / "config.json"),
        "splat_fit_over_input": ("splat", "fit", cloud, "-o", cloud),
        "ddpm_sample_over_folder": ("ddpm", "sample", run_dir, "a head", "-o", data),
    }[case]
    before = digest(tmp_path)
    code, _, err = run(*args)
    assert one_line_error(code, err), err
    assert digest(tmp_path) == before


@pytest.mark.parametrize("argv", [
    ("ddpm", "sample", "r", "p", "-o", "o", "--guidance", "nan"),
    ("ddpm", "sample", "r", "p", "-o", "o", "--guidance", "-1"),
    ("ddpm", "train", "d", "-o", "r", "--batch", "0"),
    ("ddpm", "train", "d", "-o", "r", "--lr", "nan"),
    ("talk", "synth", "-o", "o", "--fps", "nan"),
    ("talk", "synth", "-o", "o", "--fps", "0"),
    ("talk", "animate", "m", "--audio", "a.wav", "-o", "o", "--fps", "-5"),
    ("talk", "train", "d", "-o", "m", "--stage-scale", "0"),
    ("hmd", "synth", "-o", "o", "--motion", "nan"),
    ("hmd", "train", "r", "-o", "m", "--ema", "1.2"),
    ("splat", "fit", "m.ply", "-o", "o.ply", "--threads", "-1"),
    ("texture", "train", "d", "-o", "m", "--k", "0"),
    ("convert", "a.obj", "-o", "o", "--smooth", "1000000000"),
    ("convert", "a.obj", "-o", "o", "--res", "3"),
    ("convert", "a.obj", "-o", "o", "--lam", "inf"),
    ("synth", "surface", "torus", "-o", "t.obj", "--resolution", "1000000000"),
    ("synth", "head", "-o", "h.obj", "--seed", "-3"),
    ("dataset", "build", "i", "-o", "o", "--workers", "0"),
])
def test_numeric_options_have_ranges(tmp_path, argv):
    code, _, err = run(*argv, cwd=tmp_path)
    assert code == 2 and "error: argument" in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


def _png_header(path: Path, w: int, h: int) -> None:
    import struct
    import zlib

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(ihdr)) + chunk + struct.pack(">I", zlib.crc32(chunk)))


@pytest.mark.parametrize("case", ["meta_null", "meta_strings", "png_60000", "manifest_binary"])
def test_corrupt_geometry_image_and_dataset_files(demo, tmp_path, case):
    import shutil

    d, _ = demo
    gim = tmp_path / "gim"
    shutil.copytree(d / "head_gim", gim)
    if case == "meta_null":
        (gim / "meta.json").write_text("null")
    elif case == "meta_strings":
        meta = json.loads((gim / "meta.json").read_text())
        meta["version"], meta["bbox_min"] = "2", ["a", "b", "c"]
        (gim / "meta.json").write_text(json.dumps(meta))
    elif case == "png_60000":
        _png_header(gim / "position.png", 60000, 60000)
    if case == "manifest_binary":
        data = tmp_path / "ds"
        data.mkdir()
        (data / "manifest.jsonl").write_bytes(bytes(range(256)) * 4)
        code, _, err = run("ddpm", "train", data, "-o", tmp_path / "run", "--steps", "1", "--tiny")
        assert one_line_error(code, err), err
        return
    code, _, err = run("reconstruct", gim, "-o", tmp_path / "rec.obj")
    assert one_line_error(code, err), err
    assert not (tmp_path / "rec.obj").exists()


@pytest.mark.parametrize("case", ["hmd_version_99", "talk_field_type", "hmd_binary_config", "ddpm_field_type",
                                  "texture_field_type"])
def test_model_folders_are_validated(tmp_path, case):
    """A model folder's config is read through one validated schema: a newer format, a field
    of the wrong type or a binary file is one line naming the file and the field."""
    m = tmp_path / "m"
    m.mkdir()
    (m / "model.safetensors").write_bytes(b"\0" * 16)
    data = tmp_path / "d"
    data.mkdir()
    if case == "hmd_version_99":
        (m / "config.json").write_text(json.dumps({"format": "geoface-hfm-gs", "version": 99, "config": {}}))
        argv, want = ("hmd", "eval", m, data), "newer"
    elif case == "talk_field_type":
        (m / "config.json").write_text(json.dumps({"format": "geoface-thgs", "version": 1, "config": {"iters": "many"}}))
        argv, want = ("talk", "eval", m, data), "'iters'"
    elif case == "hmd_binary_config":
        (m / "config.json").write_bytes(bytes(range(256)))
        argv, want = ("hmd", "eval", m, data), "config.json"
    elif case == "ddpm_field_type":
        (m / "checkpoint").mkdir()
        (m / "checkpoint" / "config.json").write_text(json.dumps({"res": "64"}))
        argv, want = ("ddpm", "sample", m, "a head", "-o", tmp_path / "out"), "'res'"
    else:
        (m / "config.json").write_text(json.dumps({"gde_res": [1, 2]}))
        (tmp_path / "p.png").write_bytes(b"")
        import cv2

        cv2.imwrite(str(tmp_path / "p.png"), np.zeros((32, 32, 3), np.uint8))
        argv, want = ("texture", "reconstruct", tmp_path / "p.png", "--model", m, "-o", tmp_path / "out"), "gde_res"
    code, _, err = run(*argv)
    assert one_line_error(code, err) and want in err, err


def test_bad_audio_and_template_are_one_line(tmp_path):
    """A truncated or 1 Hz WAV, a truncated template.npz: one line, exit 2."""
    import wave

    from geoface.avatar.audio import read_wav
    from geoface.errors import AvatarError
    from geoface.avatar.template import Template

    def write_wav(path, rate, n):
        with wave.open(str(path), "wb") as f:
            f.setnchannels(1)
            f.setsampwidth(2)
            f.setframerate(rate)
            f.writeframes(np.zeros(n, np.int16).tobytes())

    w = tmp_path / "slow.wav"
    write_wav(w, 1, 100)
    with pytest.raises(AvatarError, match="sample rate 1 Hz"):
        read_wav(w)
    good = tmp_path / "good.wav"
    write_wav(good, 16000, 16000)
    cut = tmp_path / "cut.wav"
    cut.write_bytes(good.read_bytes()[:30])
    with pytest.raises(AvatarError, match="not a readable WAV"):
        read_wav(cut)
    npz = tmp_path / "template.npz"
    np.savez(npz, V=np.zeros((3, 3)), F=np.zeros((1, 3), int))
    (tmp_path / "cut.npz").write_bytes(npz.read_bytes()[:40])
    with pytest.raises(AvatarError, match="not a geoface template"):
        Template.load(tmp_path / "cut.npz")


def test_failed_synth_leaves_no_folder(tmp_path, monkeypatch):
    """talk/hmd/texture synth write into a temporary folder: a failure leaves nothing."""
    import geoface.thgs.data as td
    from geoface.cli import main

    def boom(out, **kw):
        (Path(out) / "frames").mkdir(parents=True)
        (Path(out) / "frames" / "0000.png").write_bytes(b"partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(td, "make_synthetic_talking", boom)
    assert main(["talk", "synth", "-o", str(tmp_path / "talk"), "-q"]) == 130
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_killed_dataset_build_stops_its_workers(tmp_path, sig):
    """SIGTERM or SIGKILL of the driver: no worker of ours is alive within 5 s, and a rerun
    finishes the build and leaves no temporary folder of the interrupted one."""
    heads = tmp_path / "heads"
    heads.mkdir()
    for s in range(2):
        assert run("synth", "head", "-o", heads / f"t{s}.obj", "--vertices", "8000", "--seed", s)[0] == 0
    out = tmp_path / "ds"
    argv = ("dataset", "build", heads, "-o", out, "--res", "128", "--augment", "2", "--workers", "2", "--no-find-face")
    p = subprocess.Popen([sys.executable, "-m", "geoface", "--quiet", *map(str, argv)])
    # kill it while its workers convert (not after a fixed delay: a fast machine finishes first)
    deadline = time.time() + 60
    while time.time() < deadline and p.poll() is None and not [
            q for q in _our_processes("multiprocessing.spawn") if _parent(q) == p.pid]:
        time.sleep(0.1)
    time.sleep(1.5)
    assert p.poll() is None, "the build finished before it could be interrupted"
    t = time.time()
    p.send_signal(sig)
    p.wait(timeout=10)
    assert p.returncode == (143 if sig == signal.SIGTERM else -9)
    while time.time() - t < 5.0 and [q for q in _our_processes("multiprocessing.spawn") if _parent(q) in (p.pid, 1)]:
        time.sleep(0.2)
    assert time.time() - t < 5.0
    if sig == signal.SIGTERM:  # the driver cleans what its stopped workers were writing
        assert [x for x in out.rglob(".*geoface-*")] == []
    code, _, err = run(*argv)
    assert code == 0, err
    assert [x for x in out.rglob(".*geoface-*")] == []


def test_device_cuda_without_a_gpu_is_one_line(tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    (tmp_path / "data").mkdir()
    code, _, err = run("ddpm", "train", tmp_path / "data", "-o", tmp_path / "run", "--device", "cuda", "--steps", "1")
    assert one_line_error(code, err) and "CUDA" in err, err
    assert not (tmp_path / "run").exists()


_UNDER_THREADS = """
import argparse, os, signal, sys, threading
import numpy as np
from scipy.spatial import cKDTree
import geoface.cli as cli

def slow(args):  # the main thread waits on SciPy's query threads nearly all the time
    rng = np.random.default_rng(0)
    tree = cKDTree(rng.random((100000, 3)))
    q = rng.random((400000, 3))
    threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGTERM)).start()
    for _ in range(200):
        tree.query(q, k=4, workers=4)

cli.main = lambda: cli._run(argparse.Namespace(func=slow, command="slow"))
cli.entry()
"""


def test_sigterm_under_native_worker_threads_exits_cleanly(tmp_path):
    """SIGTERM while SciPy's query threads run: raising at once abandons their join, frees
    their buffers and segfaults (6 of 6 runs before the deferral); deferred, it exits 143."""
    script = tmp_path / "under_threads.py"
    script.write_text(_UNDER_THREADS)
    for _ in range(2):
        t0 = time.monotonic()
        p = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
        assert p.returncode == 143, (p.returncode, p.stderr[-2000:])
        assert p.stderr.strip() == "geoface: terminated"
        assert time.monotonic() - t0 < 30.0


def test_an_interrupt_is_not_raised_where_python_would_ignore_it():
    """A signal landing in a finaliser or a WeakSet callback would be printed and ignored
    ("Exception ignored in"), and the run would go on: the handler waits for other code."""
    from geoface.cli.interrupt import _swallowed

    seen = []

    class Finalised:
        def __del__(self):
            seen.append(_swallowed(sys._getframe()))

    Finalised()
    assert seen == [True] and not _swallowed(sys._getframe()) and not _swallowed(None)
    # WeakSet's callback runs in _weakrefset.py: a frame of that file counts
    import _weakrefset

    code = compile("import sys; f = sys._getframe()", _weakrefset.__file__, "exec")
    env: dict = {}
    exec(code, env)
    assert _swallowed(env["f"])
