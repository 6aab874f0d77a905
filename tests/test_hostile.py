"""Hostile inputs and broken machines: links never written through, devices and FIFOs never
replaced, files an input references never outputs, side files named after their mesh, folder
outputs complete or absent, a full disk as one line, reads that are right (OBJ relative
indices, OFF colours) and public entries that refuse wrong types in one line."""
from __future__ import annotations

import os
import re
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from geoface.errors import GeofaceError
from geoface.mesh.io import load_mesh, save_mesh
from tests.helpers import geoface

SPOT = Path(__file__).parent / "data" / "meshes" / "spot.obj"


def run(*args, cwd=None):
    return geoface(*args, cwd=cwd)  # in this process (tests.helpers.geoface)


def one_line_error(code, err):
    return code == 2 and ": error: " in err and len(err.strip().splitlines()) == 1


def _tet(tmp_path, name="t.obj"):
    p = tmp_path / name
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n")
    return p


# ------------------------------------------------------------------ links, devices, references
def test_a_link_is_never_written_through(tmp_path):
    src = _tet(tmp_path)
    user = tmp_path / "users_file.obj"
    user.write_text("mine\n")
    link = tmp_path / "out.obj"
    link.symlink_to(user)
    code, _, err = run("repair", src, "-o", link)
    assert one_line_error(code, err) and "symbolic link" in err
    code, _, err = run("repair", src, "-o", link, "--force")  # --force replaces the link itself
    assert code == 0, err
    assert user.read_text() == "mine\n" and not link.is_symlink() and len(load_mesh(link).F) >= 3


def test_a_fifo_is_never_replaced(tmp_path):
    src = _tet(tmp_path)
    fifo = tmp_path / "pipe.obj"
    os.mkfifo(fifo)
    code, _, err = run("repair", src, "-o", fifo, "--force")
    assert one_line_error(code, err) and "FIFO" in err
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


@pytest.mark.parametrize("verb", [("repair", "-o", "x.obj"), ("convert", "-o", "xo"), ("inspect",), ("track", "-o", "t.json")])
def test_an_input_that_is_a_link_loop_a_device_or_a_fifo_is_one_line(tmp_path, verb):
    """An input that is a loop of symbolic links, a link to /dev/zero or a FIFO: one line and exit 2
    at once (not a traceback, not a read that never ends)."""
    (tmp_path / "loop.obj").symlink_to("loop.obj")
    (tmp_path / "zero.obj").symlink_to("/dev/zero")
    os.mkfifo(tmp_path / "pipe.obj")
    for name, why in (("loop.obj", "loop of symbolic links"), ("zero.obj", "character device"), ("pipe.obj", "FIFO")):
        code, _, err = run(verb[0], name, *verb[1:], cwd=tmp_path)
        assert one_line_error(code, err) and why in err, (verb, name, err)


def test_files_an_input_references_are_never_outputs(tmp_path):
    """An OBJ whose MTL and texture are not named after it: neither may become an output,
    --force or not (the guard runs before any work)."""
    (tmp_path / "shared.mtl").write_text("newmtl m\nmap_Kd skin.png\n")
    (tmp_path / "skin.png").write_bytes(b"\x89PNG not really")
    obj = tmp_path / "head.obj"
    obj.write_text("mtllib shared.mtl\nusemtl m\n" + _tet(tmp_path, "x.obj").read_text())
    before = {p: p.read_bytes() for p in (tmp_path / "shared.mtl", tmp_path / "skin.png")}
    for out in ("skin.png", "shared.mtl"):
        code, _, err = run("view", obj, "--screenshot", tmp_path / out, "--force")
        assert one_line_error(code, err) and "input" in err, err
    code, _, err = run("inspect", obj, "--json", tmp_path / "shared.mtl", "--force")
    assert one_line_error(code, err), err
    assert {p: p.read_bytes() for p in before} == before


def test_gltf_side_files_are_named_after_their_mesh(tmp_path):
    from geoface.synth import sphere

    (tmp_path / "gltf_buffer_0.bin").write_bytes(b"a user's file")
    V1, F1 = sphere(1.0, 2)
    V2, F2 = sphere(3.0, 1)
    save_mesh(tmp_path / "a.gltf", V=V1, F=F1)
    save_mesh(tmp_path / "b.gltf", V=V2, F=F2)  # beside a.gltf: a keeps its own geometry
    assert (tmp_path / "gltf_buffer_0.bin").read_bytes() == b"a user's file"
    assert {p.name for p in tmp_path.iterdir()} == {"a.gltf", "a.bin", "b.gltf", "b.bin", "gltf_buffer_0.bin"}
    a, b = load_mesh(tmp_path / "a.gltf"), load_mesh(tmp_path / "b.gltf")
    assert len(a.V) == len(V1) and np.abs(a.V).max() == pytest.approx(1.0, rel=1e-6)
    assert len(b.V) == len(V2) and np.abs(b.V).max() == pytest.approx(3.0, rel=1e-6)
    # the buffer is covered by the existence check
    (tmp_path / "c.bin").write_bytes(b"mine")
    code, _, err = run("repair", _tet(tmp_path), "-o", tmp_path / "c.gltf")
    assert one_line_error(code, err) and "c.bin" in err
    assert (tmp_path / "c.bin").read_bytes() == b"mine"


# ------------------------------------------------------------------ folders and videos
def test_a_model_folder_of_a_users_files_needs_force(tmp_path):
    m = tmp_path / "M"
    m.mkdir()
    (m / "config.json").write_text('{"mine": 1}')
    for argv in (("talk", "train", tmp_path / "data", "-o", m), ("hmd", "train", tmp_path / "reg", "-o", m)):
        (tmp_path / "data").mkdir(exist_ok=True)
        (tmp_path / "reg").mkdir(exist_ok=True)
        code, _, err = run(*argv)
        assert one_line_error(code, err), err
        assert (m / "config.json").read_text() == '{"mine": 1}' and sorted(p.name for p in m.iterdir()) == ["config.json"]


def test_a_killed_video_leaves_nothing_the_next_run_does_not_clean(tmp_path):
    from geoface.video import probe_video, write_video

    stale = tmp_path / f".t.mp4.geoface-{2 ** 22 + 12345}-abc.tmp.mp4"  # a dead process's temporary
    stale.write_bytes(b"half a video")
    frames = [np.full((32, 48, 3), k * 20, np.uint8) for k in range(10)]
    write_video(frames, tmp_path / "t.mp4", fps=10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.mp4"]
    assert probe_video(tmp_path / "t.mp4")["frames"] == 10
    assert stat.S_IMODE(os.stat(tmp_path / "t.mp4").st_mode) == 0o666 & ~_umask()


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


def test_ffmpeg_failure_is_one_line(tmp_path):
    from geoface.video import write_video

    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o555)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("root writes into read-only folders")
        with pytest.raises(GeofaceError) as e:
            write_video([np.zeros((16, 16, 3), np.uint8)] * 3, ro / "v.mp4")
        assert "\n" not in str(e.value)
    finally:
        os.chmod(ro, 0o755)
    with pytest.raises(GeofaceError):
        write_video([np.zeros((16, 16, 3), np.uint8)], tmp_path / "v.mp4", fps=0.001)


@pytest.fixture
def full_disk(tmp_path):
    """A 256 KiB tmpfs (root only): a few small files fit, a dataset's second item does not."""
    if os.geteuid() != 0 or not shutil.which("mount"):
        pytest.skip("a small tmpfs needs root")
    d = tmp_path / "full"
    d.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(d)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        yield d
    finally:
        subprocess.run(["umount", "-l", str(d)], capture_output=True)


def test_a_full_disk_is_one_line_and_leaves_nothing(full_disk):
    from geoface.video import write_video

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (256, 256, 3), dtype=np.uint8) for _ in range(40)]  # noise: megabytes of H.264
    with pytest.raises(GeofaceError) as e:
        write_video(frames, full_disk / "v.mp4", fps=25)
    assert "\n" not in str(e.value)
    assert list(full_disk.iterdir()) == []
    code, _, err = run("synth", "head", "-o", full_disk / "h.obj", "--vertices", "200000")
    assert one_line_error(code, err), err
    assert list(full_disk.iterdir()) == []


# ------------------------------------------------------------------ reads and entries
def test_obj_relative_indices_count_from_where_they_stand(tmp_path):
    p = tmp_path / "rel.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 0 0\nv 6 0 0\nv 5 1 0\nf -3 -2 -1\n")
    m = load_mesh(p)
    from geoface.mesh import topology_report

    assert len(m.V) == 6 and sorted(map(sorted, m.F.tolist())) == [[0, 1, 2], [3, 4, 5]]
    assert topology_report(m.V, m.F).components == 2


def test_off_vertex_colours_are_read(tmp_path):
    p = tmp_path / "c.off"
    p.write_text("COFF\n# colours\n4 2 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n0 1 0 0 0 255 255\n"
                 "1 1 0 255 255 255 128\n3 0 1 2\n4 1 3 2 0\n")
    m = load_mesh(p)
    assert len(m.F) == 3  # the quad as two triangles
    assert m.colors is not None and np.allclose(m.colors[0], [1, 0, 0, 1]) and np.allclose(m.colors[3, 3], 128 / 255)
    q = tmp_path / "plain.off"
    q.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert load_mesh(q).colors is None
    bad = tmp_path / "bad.off"
    bad.write_text("OFF\n3 5 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    with pytest.raises(GeofaceError, match="promises"):
        load_mesh(bad)


def test_public_entries_refuse_wrong_types():
    from geoface.gimage.image import save_gimage
    from geoface.mesh import topology_report
    from geoface.mesh.io import Mesh
    from geoface.param.ricci import RicciFlowSolver
    from geoface.param.corners import default_corners
    from geoface.synth import square_grid

    V, F = square_grid(20)  # 400 vertices
    with pytest.raises(GeofaceError, match="uint8"):
        topology_report(V, F.astype(np.uint8))
    with pytest.raises(GeofaceError, match="integer"):
        topology_report(V, F.astype(bool))
    assert topology_report(V, F.astype(np.uint16)).is_disk
    c = default_corners(V, F)
    s = RicciFlowSolver(V, F)
    with pytest.raises(GeofaceError, match="integer"):
        s.solve(c + 0.5)
    with pytest.raises(GeofaceError):
        save_gimage("/tmp/never-written", {"positions": 1})
    assert not Path("/tmp/never-written").exists()
    m = Mesh(V, F)
    with pytest.raises(GeofaceError, match="vertex_map"):
        m.with_geometry(V, F, np.arange(5), np.arange(len(F)))
    with pytest.raises(GeofaceError, match="face_map"):
        m.with_geometry(V, F, np.arange(len(V)), np.full(len(F), 10 ** 6))


def test_safetensors_get_the_users_umask(tmp_path):
    from geoface.ddpm.data import DataStats

    st = DataStats(mean=np.zeros((3, 4, 4), np.float32), std=np.ones(3, np.float32), bound=1.0)
    st.save(tmp_path / "s.safetensors")
    assert stat.S_IMODE(os.stat(tmp_path / "s.safetensors").st_mode) == 0o666 & ~_umask()


def test_a_dataset_build_on_a_full_disk_stops_with_one_line(full_disk, tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(SPOT, src / "spot.obj")
    code, _, err = run("dataset", "build", src, "-o", full_disk / "ds", "--res", "128", "--augment", "3", "--workers", "1")
    assert one_line_error(code, err) and "space" in err.lower(), err
    assert re.search(r"\(([1-9]\d*) items? built (are|is) kept", err), err  # it stopped part way, keeping what fit
    leftovers = [p.name for p in full_disk.rglob("*") if ".geoface-" in p.name or p.name.endswith(".tmp")]
    assert leftovers == []


@pytest.mark.parametrize("field,value", [("res", -1), ("norm_num_groups", 0), ("num_train_timesteps", 0),
                                         ("text_max_length", -1), ("lr", float("nan")), ("block_out_channels", (64, 0)),
                                         ("ema_decay", 1.0), ("batch_size", True)])
def test_ddpm_configs_are_bounded(field, value):
    from geoface.ddpm.model import DDPMConfig

    with pytest.raises(GeofaceError, match=field):
        DDPMConfig(**{field: value})


@pytest.mark.parametrize("state", [[], {}, {"step": 1, "bbox_min": [0, 0, 0], "bbox_max": [1, float("nan"), 1]},
                                   {"step": -1, "bbox_min": [0, 0, 0], "bbox_max": [1, 1, 1]},
                                   {"step": 1, "bbox_min": [0, 0, 0], "bbox_max": [1, 0, 1]}])
def test_ddpm_state_files_are_checked(state, tmp_path):
    from geoface.ddpm.checkpoint import check_state

    with pytest.raises(GeofaceError):
        check_state(state, tmp_path / "state.json")
    check_state({"step": 3, "bbox_min": [0, 0, 0], "bbox_max": [1, 1, 1]}, tmp_path / "state.json")


@pytest.mark.parametrize("spec", ["hash:abc", "hash:-5", "hash:0", "hash:", "nonsense"])
def test_text_encoder_specs(spec):
    from geoface.ddpm.text import make_text_encoder

    with pytest.raises(GeofaceError):
        make_text_encoder(spec)
    assert make_text_encoder("hash:16").encode(["a head"]).shape[-1] == 16


def test_texture_and_camera_and_gimage_values_are_checked(tmp_path):
    from geoface.texture.model import TextureTrainConfig
    from geoface.avatar.capture import camera_from_json

    for kw in ({"k": 0}, {"gde_res": 1e9}, {"epochs": (1, 2)}, {"lr": -1.0}):
        with pytest.raises(GeofaceError):
            TextureTrainConfig(**kw)
    good = {"fx": 100.0, "fy": 100.0, "cx": 64, "cy": 64, "width": 128, "height": 128,
            "R": np.eye(3).tolist(), "t": [0, 0, 1]}
    assert camera_from_json(good).width == 128
    (tmp_path / "camera.json").write_text('{"fx": 1, ')
    with pytest.raises(GeofaceError, match="JSON"):
        camera_from_json(tmp_path / "camera.json")
    for bad in ({**good, "fx": -1}, {**good, "width": 0}, {**good, "R": [[1, 0], [0, 1]]},
                {**good, "R": (2 * np.eye(3)).tolist()}, {k: v for k, v in good.items() if k != "t"}):
        with pytest.raises(GeofaceError):
            camera_from_json(bad)
    # a geometry image whose uv_orientation is not +-1
    import json

    from geoface.gimage.image import GeometryImage, load_gimage, save_gimage

    N = 8
    gi = GeometryImage(np.zeros((6, N, N), np.float32), np.ones((N, N), bool),
                       {"bbox_min": [0, 0, 0], "bbox_max": [1, 1, 1], "channels": ["px", "py", "pz", "nx", "ny", "nz"],
                        "resolution": N, "version": 1})
    save_gimage(tmp_path / "g", gi)
    meta = json.loads((tmp_path / "g" / "meta.json").read_text())
    meta["uv_orientation"] = "x"
    (tmp_path / "g" / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(GeofaceError, match="uv_orientation"):
        load_gimage(tmp_path / "g")


@pytest.mark.parametrize("argv", [
    ("inspect", "a\nb.obj"),
    ("convert", str(SPOT), "-o", "o", "--corner-set", "3", "--augment", "4"),
    ("synth", "ict", "-o", "h.obj", "--identity", "1e6"),
    ("synth", "ict", "-o", "h.obj", "--identity", ""),
    ("param", str(SPOT), "-o", "x.stl"),
    ("dataset", "build", ".", "-o", "out", "--up", "w"),
    ("view", "--web", str(SPOT), "--host", "not a host"),
    ("repair", str(SPOT), "-o", "x.fbx"),
    ("reconstruct", str(Path(__file__).parent), "-o", "rec.usd"),
    ("inspect", str(Path(__file__).parent)),
])
def test_odd_values_are_one_line_before_any_work(argv, tmp_path):
    code, _, err = run(*argv, cwd=tmp_path)
    assert one_line_error(code, err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_landmark_files_are_bounded(tmp_path):
    import json

    from geoface.synth.ict_fit import load_landmarks

    good = (np.random.default_rng(0).random((68, 2)) * 200).tolist()
    cases = {"size": {"landmarks": good, "image_size": [1e999, 10]}, "huge": {"landmarks": (np.array(good) * 1e300).tolist()},
             "point": {"landmarks": [[5.0, 5.0]] * 68}}
    for name, d in cases.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(d).replace("Infinity", "1e999"))
        with pytest.raises(GeofaceError):
            load_landmarks(tmp_path / f"{name}.json")
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(GeofaceError):
        load_landmarks(tmp_path / "deep.json")
    (tmp_path / "ok.json").write_text(json.dumps({"landmarks": good, "image_size": [256, 256]}))
    assert load_landmarks(tmp_path / "ok.json")[1] == (256, 256)


def _fill(folder: Path) -> None:
    """Fill the file system of ``folder`` to the last block (with a file kept there)."""
    fd = os.open(folder / "ballast", os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        for size in (65536, 512, 1):
            try:
                while True:
                    os.write(fd, b"\0" * size)
            except OSError:
                pass
    finally:
        os.close(fd)


def test_ddpm_train_on_a_full_disk_is_one_line_and_leaves_no_run(full_disk, tmp_path):
    from tests.ddpm.conftest import make_gimage_dataset

    data = make_gimage_dataset(tmp_path / "data", n_items=4, N=16)
    _fill(full_disk)
    code, _, err = run("ddpm", "train", data, "-o", full_disk / "run", "--res", "8", "--steps", "2", "--batch", "2",
                       "--text-encoder", "hash:8", "--tiny", "--checkpoint-every", "1")
    assert one_line_error(code, err), err
    assert sorted(p.name for p in full_disk.iterdir()) == ["ballast"]


def test_one_vocabulary_for_up():
    """Every --up takes the same values: y, +y, -z, three numbers."""
    from geoface.mesh.frame import parse_up
    from geoface.repair.opening import as_axis

    for a, b in (("y", "+y"), ("-z", "0,0,-1"), ("x", "+X")):
        assert np.allclose(as_axis(a), as_axis(b)) and np.allclose(as_axis(a), parse_up(b))
    with pytest.raises(GeofaceError):
        as_axis("w")


@pytest.mark.parametrize("args,why", [
    (("convert", "h.obj", "-o", "o", "--up", "y", "--front", "y"), "parallel"),
    (("convert", "h.obj", "-o", "o", "--up", "y", "--front=-y"), "parallel"),
    (("track", "h.obj", "-o", "t.json", "--smooth", "--fps", "inf"), "--fps"),
    (("track", "h.obj", "-o", "t.json", "--fps", "0"), "--fps"),
    (("track", "h.obj", "-o", "t.json", "--fps", "nan"), "--fps"),
])
def test_contradictory_or_infinite_options_are_one_line(tmp_path, args, why):
    """Up and front along one axis, a frame rate of 0, inf or NaN: one line, exit 2, nothing written."""
    _tet(tmp_path, "h.obj")
    code, _, err = run(*args, cwd=tmp_path)
    assert one_line_error(code, err) and why in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.obj"]


def test_the_tracker_refuses_a_frame_rate_that_is_not_one(tmp_path):
    from geoface.track import track_input

    for bad in (0, -1, float("inf"), float("nan")):
        with pytest.raises(GeofaceError, match="fps"):
            track_input(tmp_path / "x.png", tmp_path / "t.json", fps=bad)


def test_two_frames_of_one_name_are_refused_before_their_masks_collide(tmp_path):
    """A folder with 0000.png and 0000.jpg: their masks would both be 0000.png (one lost)."""
    from geoface.images import save_image

    frames = tmp_path / "frames"
    frames.mkdir()
    img = np.zeros((32, 32, 3), np.uint8)
    for name in ("0000.png", "0000.jpg", "0001.png"):
        save_image(frames / name, img)
    code, _, err = run("track", frames, "-o", tmp_path / "t.json", "--masks", tmp_path / "m")
    assert one_line_error(code, err) and "'0000'" in err, err
    assert not (tmp_path / "m").exists() and not (tmp_path / "t.json").exists()


@pytest.mark.parametrize("bad", ["zero", "fifo", "loop"])
def test_a_capture_holding_a_device_a_fifo_or_a_folder_loop_is_one_line(tmp_path, bad):
    """``ln -s /dev/zero cap/zero.bin; geoface track cap -o t`` once copied zeros until the disk was
    full; a FIFO would block for ever; a folder linking to its capture loops. One line, exit 2,
    nothing written, at once."""
    from geoface.images import save_image

    cap = tmp_path / "cap"
    (cap / "frames").mkdir(parents=True)
    save_image(cap / "frames" / "0000.png", np.zeros((32, 32, 3), np.uint8))
    if bad == "zero":
        (cap / "zero.bin").symlink_to("/dev/zero")
    elif bad == "fifo":
        os.mkfifo(cap / "pipe")
    else:
        (cap / "frames" / "up").symlink_to(cap)
    p = subprocess.run([sys.executable, "-m", "geoface", "--quiet", "track", str(cap), "-o", str(tmp_path / "t")],
                       capture_output=True, text=True, timeout=60)
    assert one_line_error(p.returncode, p.stderr), p.stderr
    assert not (tmp_path / "t").exists()


def test_a_screenshot_over_the_meta_file_or_not_an_image_is_refused(tmp_path):
    """``view scan.obj --meta scan.json --screenshot scan.json --force`` once reached OpenCV with a
    JSON path: the screenshot must be an image path, and --meta is an input no output replaces."""
    _tet(tmp_path, "h.obj")
    (tmp_path / "m.json").write_text("{}")
    (tmp_path / "m.png").write_text("{}")
    for meta, shot, why in (("m.json", "m.json", ".png or .jpg"), ("m.png", "m.png", "input")):
        code, _, err = run("view", "h.obj", "--meta", meta, "--screenshot", shot, "--force", cwd=tmp_path)
        assert one_line_error(code, err) and why in err, err
    assert (tmp_path / "m.json").read_text() == "{}" and (tmp_path / "m.png").read_text() == "{}"


def test_an_interrupt_as_a_command_returns_is_no_traceback(monkeypatch, capsys):
    """Ctrl-C landing as a command finishes (talk animate, hmd remove) once printed a
    KeyboardInterrupt traceback and exited 0: the run ends as the command did, quietly; one that
    lands while it works is "interrupted", 130."""
    import argparse

    import geoface.cli as cli

    def finished_then_interrupted(args):
        return 0

    class Late:  # the interrupt arrives as the handlers are being restored
        def __enter__(self):
            return []

        def __exit__(self, *exc):
            raise KeyboardInterrupt

    monkeypatch.setattr("geoface.cli.interrupt.deferred_interrupts", lambda: Late())
    args = argparse.Namespace(func=finished_then_interrupted, command="x", what=None)
    assert cli._run(args) == 0

    def interrupted(args):
        raise KeyboardInterrupt

    assert cli._run(argparse.Namespace(func=interrupted, command="x", what=None)) == 130
    assert "Traceback" not in capsys.readouterr().err


def test_a_huge_photo_is_refused_before_it_is_decoded(tmp_path):
    """A 16000² PNG once ran the tracker out of memory (numpy's _ArrayMemoryError): its header is
    read first, and more than 100 megapixels is one line."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 16000, 16000, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(b"\x00" * 100)) + chunk(b"IEND", b""))
    (tmp_path / "huge.png").write_bytes(png)
    code, _, err = run("track", "huge.png", "-o", "t.json", cwd=tmp_path)
    assert one_line_error(code, err) and "16000x16000" in err, err
