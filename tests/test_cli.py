"""The `geoface` command: reports, outputs, and one-line errors with exit code 2."""

import json

import numpy as np
import pytest

from geoface.cli import main
from geoface.mesh import topology_report
from geoface.mesh.io import load_mesh, save_mesh
from geoface.synth import torus
from tests.helpers import geoface, shared_mesh


def run(*args):
    """The console command (in this process: ``tests.helpers.geoface``)."""
    return geoface(*args)


def test_inspect_json_and_text(capsys):
    path = shared_mesh("spot.obj")
    assert main(["inspect", str(path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["closed"] and d["genus"] == 0 and d["attributes"]["uv"]
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "genus               0" in out and "closed              True" in out


def test_json_is_one_option_everywhere(tmp_path, capsys):
    """--json PATH writes the file beside the text; a bare --json (or -) prints JSON instead."""
    path = shared_mesh("spot.obj")
    js = tmp_path / "r.json"
    assert main(["inspect", str(path), "--json", str(js)]) == 0
    assert "genus" in capsys.readouterr().out and json.loads(js.read_text())["genus"] == 0
    assert main(["inspect", str(path), "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["closed"]
    assert main(["repair", str(path), "-o", str(tmp_path / "d.obj"), "--json", str(tmp_path / "d.json")]) == 0
    assert "->" in capsys.readouterr().out and json.loads((tmp_path / "d.json").read_text())["report"]["is_disk"]
    assert main(["inspect", str(path), "--json", str(js)]) == 2  # an output that exists needs --force
    from geoface.cli import build_parser

    for argv in (["inspect", "a.obj"], ["repair", "a.obj", "-o", "b.obj"], ["param", "a.obj", "-o", "b.obj"],
                 ["hmd", "eval", "m", "u"], ["talk", "eval", "m", "d"]):
        assert build_parser().parse_args(argv + ["--json"]).json == "-"
        assert build_parser().parse_args(argv + ["--json", "x.json"]).json == "x.json"


def test_repair_writes_a_disk_keeping_uvs(tmp_path, capsys):
    out = tmp_path / "spot_disk.obj"
    assert main(["repair", str(shared_mesh("spot.obj")), "-o", str(out), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["report"]["is_disk"]
    m = load_mesh(out)
    assert topology_report(m.V, m.F).is_disk
    assert m.UV is not None  # the texture coordinates came along


def test_repair_closed_torus_with_options(tmp_path):
    V, F = torus(1.0, 0.3, 32, 16)
    src = tmp_path / "t.ply"
    save_mesh(src, V=V, F=F)
    code, out, err = run("repair", src, "-o", tmp_path / "t_disk.ply", "--up", "z", "--open", "cap")
    assert code == 0, err
    assert "cut_handle" in out and "open_cap" in out
    m = load_mesh(tmp_path / "t_disk.ply")
    assert topology_report(m.V, m.F).is_disk


BAD = {
    "empty.obj": b"",
    "text.obj": b"this is not a mesh\n",
    "cloud.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\n",
    "nan.obj": b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n",
    "range.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
    "garbage.ply": bytes(np.random.default_rng(0).integers(0, 256, 400, dtype=np.uint8)),
}


@pytest.mark.parametrize("name", sorted(BAD))
@pytest.mark.parametrize("verb", ["inspect", "repair"])
def test_bad_input_one_line_exit_2_no_output(tmp_path, name, verb):
    src = tmp_path / name
    src.write_bytes(BAD[name])
    out = tmp_path / "out.obj"
    args = [verb, src] + (["-o", out] if verb == "repair" else [])
    code, stdout, stderr = run(*args)
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("geoface: error:"), stderr
    assert "Traceback" not in stderr
    assert not out.exists()
    assert list(tmp_path.iterdir()) == [src]  # no partial or temporary file left


def test_failed_repair_keeps_existing_output(tmp_path):
    src = tmp_path / "nan.obj"
    src.write_bytes(BAD["nan.obj"])
    out = tmp_path / "out.obj"
    out.write_text("precious")
    code, _, _ = run("repair", src, "-o", out)
    assert code == 2 and out.read_text() == "precious"


def test_refuses_to_overwrite_input(tmp_path):
    V, F = torus(1.0, 0.3, 16, 8)
    src = tmp_path / "t.obj"
    save_mesh(src, V=V, F=F)
    before = src.read_bytes()
    code, _, err = run("repair", src, "-o", src)
    assert code == 2 and "overwrite the input" in err
    assert src.read_bytes() == before


def test_usage_errors_are_one_line(tmp_path):
    code, _, err = run("repair", tmp_path / "x.obj")
    assert code == 2 and len(err.strip().splitlines()) == 1
    code, _, err = run("repair", tmp_path / "x.obj", "-o", tmp_path / "y.obj", "--open", "sideways")
    assert code == 2 and len(err.strip().splitlines()) == 1
    code, _, err = run("inspect", tmp_path / "x.unknown")
    assert code == 2 and "unsupported mesh format" in err


def test_unwritable_output_is_a_clean_error(tmp_path):
    V, F = torus(1.0, 0.3, 16, 8)
    src = tmp_path / "t.ply"
    save_mesh(src, V=V, F=F)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = run("repair", src, "-o", blocker / "sub" / "out.ply", "--up", "z")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_synth_surface_and_version(tmp_path):
    code, out, err = run("synth", "surface", "genus2", "-o", tmp_path / "g.obj", "--resolution", "20")
    assert code == 0, err
    m = load_mesh(tmp_path / "g.obj")
    assert topology_report(m.V, m.F).genus == 2
    code, out, _ = run("--version")
    assert code == 0 and out.startswith("geoface ")


@pytest.mark.parametrize("method", ["ricci", "harmonic", "lscm"])
def test_param_writes_uvs_and_metrics(tmp_path, method):
    from geoface.synth import procedural_head

    h = procedural_head(n_vertices=3000, seed=1)
    src = tmp_path / "h.ply"
    save_mesh(src, V=h.V, F=h.F)
    out, js = tmp_path / "h_uv.obj", tmp_path / "m.json"
    code, stdout, err = run("param", src, "-o", out, "--method", method, "--json", js)
    assert code == 0, err
    assert "quasi-conformal ratio" in stdout
    m = load_mesh(out)
    assert m.UV is not None and m.UV.min() >= 0
    d = json.loads(js.read_text())
    assert d["distortion"]["flipped"] == 0 and d["method"] == method
    if method == "ricci":  # the conformal rectangle itself: height 1, width = aspect
        assert abs(m.UV[:, 1].max() - 1) < 1e-9 and abs(m.UV[:, 0].max() - d["aspect"]) < 1e-6
    else:
        assert m.UV.max() <= 1 + 1e-9


def test_param_writes_the_conformal_rectangle_not_the_stretched_square(tmp_path):
    """The conformal map is the rectangle: written as is it stays conformal (the coarse
    grid's PL map: QC mean 1.10); stretched to the square, QC grows to about the aspect
    ratio (1.68 for aspect 1.66)."""
    from geoface.synth import disk_grid

    V, F = disk_grid(16)
    V = V * np.array([2.0, 1.0, 1.0])  # an ellipse: the rectangle is far from square
    src = tmp_path / "e.ply"
    save_mesh(src, V=V, F=F)
    qc = {}
    for fit in ("rectangle", "stretch"):
        js = tmp_path / f"{fit}.json"
        code, _, err = run("param", src, "-o", tmp_path / f"{fit}.obj", "--fit", fit, "--json", js)
        assert code == 0, err
        qc[fit] = json.loads(js.read_text())
    a = qc["rectangle"]["aspect"]
    assert max(a, 1 / a) > 1.5
    assert qc["rectangle"]["distortion"]["qc_mean"] < 1.15
    assert qc["stretch"]["distortion"]["qc_mean"] > 0.95 * max(a, 1 / a)


def test_param_refuses_a_closed_mesh_unless_repaired(tmp_path):
    src = shared_mesh("spot.obj")
    code, _, err = run("param", src, "-o", tmp_path / "s.obj")
    assert code == 2 and "not a topological disk" in err and len(err.strip().splitlines()) == 1
    code, _, err = run("param", src, "-o", tmp_path / "s.obj", "--repair", "--corner-set", "3")
    assert code == 0, err
    code, _, err = run("param", src, "-o", tmp_path / "s2.obj", "--repair", "--corners", "1,2")
    assert code == 2 and "four" in err


def test_mesh_needing_intrinsic_flips_and_boundary_splits(tmp_path):
    # the repaired beetle: Ricci flow needs Ptolemy flips and pushes an interior vertex onto
    # a boundary edge, which is split; param and convert carry the new vertex through
    src = shared_mesh("beetle.obj")
    js = tmp_path / "m.json"
    code, stdout, err = run("param", src, "-o", tmp_path / "b.obj", "--repair", "--json", js)
    assert code == 0, err
    d = json.loads(js.read_text())
    assert d["intrinsic_flips"] > 0 and d["conformal_map_distortion"]["flipped"] == 0
    m = load_mesh(tmp_path / "b.obj")
    assert len(m.V) == d["vertices"] + d["split_boundary_edges"]
    code, stdout, err = run("convert", src, "-o", tmp_path / "gim", "--res", "64")
    assert code == 0, err
    st = json.loads((tmp_path / "gim" / "metrics.json").read_text())["sets"][0]
    assert st["distortion"]["flipped"] == 0 and st["reconstruction"]["hausdorff"] < 0.03


def _all_parsers(p, name="geoface"):
    import argparse

    yield name, p
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            for n, sp in a.choices.items():
                yield from _all_parsers(sp, f"{name} {n}")


def test_help_shows_every_default_and_names_outputs_one_way():
    """Every option with a default says it in --help; every verb that writes takes -o (no
    positional output); a name means one thing (--dask is the cluster, --sampler the noise schedule)."""
    import argparse

    from geoface.cli import build_parser

    writers = 0
    for name, p in _all_parsers(build_parser()):
        text = p.format_help()
        for a in p._actions:
            if a.help is argparse.SUPPRESS or not a.option_strings:
                continue
            if a.default not in (None, False, argparse.SUPPRESS) and not isinstance(a, argparse._StoreFalseAction):
                # (a --no-X switch's help says what it turns off; "(default: True)" would read backwards)
                h = p._get_formatter()._get_help_string(a) % {"default": a.default}
                assert "default" in h, (name, a.option_strings, h)
        positionals = [a.dest for a in p._actions if not a.option_strings and a.help is not argparse.SUPPRESS]
        assert not any(d in ("out_dir", "output", "out") for d in positionals), (name, positionals)
        if "-o OUT_DIR, --output OUT_DIR" in text or "-o OUTPUT, --output OUTPUT" in text:
            writers += 1
        assert "--scheduler" not in text, name
    assert writers >= 10


def test_renamed_options_and_the_old_positional_output(tmp_path, capsys):
    from geoface.cli import main

    assert main(["dataset", "ict", "-o", str(tmp_path / "d"), "--count", "1", "--scheduler", "tcp://x:1"]) == 2
    assert "--scheduler is now --dask" in capsys.readouterr().err
    assert main(["ddpm", "sample", str(tmp_path), "p", "--scheduler", "ddim", "-o", str(tmp_path / "s")]) == 2
    assert "--scheduler is now --sampler" in capsys.readouterr().err
    assert main(["convert", "a.obj"]) == 2
    assert "required: -o/--output" in capsys.readouterr().err
    # the positional output of earlier releases still works, with a one-line warning
    src = tmp_path / "t.obj"
    assert main(["synth", "surface", "disk", "-o", str(src), "-q"]) == 0
    capsys.readouterr()
    assert main(["convert", str(src), str(tmp_path / "g"), "--res", "16", "--method", "conformal"]) == 0
    err = capsys.readouterr().err
    assert "write `-o " in err and (tmp_path / "g" / "position.png").exists()


def test_convert_without_the_report(tmp_path, capsys):
    """--no-reconstruct: the images only, no reconstruction.obj and no error report."""
    from geoface.cli import main

    src = tmp_path / "d.obj"
    assert main(["synth", "surface", "disk", "-o", str(src), "-q"]) == 0
    assert main(["convert", str(src), "-o", str(tmp_path / "g"), "--res", "16", "--no-reconstruct"]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "g" / "position.png").is_file() and not (tmp_path / "g" / "reconstruction.obj").exists()
    assert "Hausdorff" not in out and "1 image set at 16x16" in out


def test_inspect_reports_the_face_it_finds(capsys):
    """`inspect` looks for the face: one line in the text (found, how, the frame), the 68
    landmarks in 3D in the JSON; none on a shape without one, and `--no-face` skips the looking."""
    path = shared_mesh("decimated-max.obj")
    assert main(["inspect", str(path)]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("face ")]
    assert len(line) == 1 and "found: 68 landmarks" in line[0] and "front" in line[0], line
    assert main(["inspect", str(path), "--json"]) == 0
    face = json.loads(capsys.readouterr().out)["face"]
    assert face["found"] and len(face["points"]) == 68 and face["up"][1] > 0.95 and face["front"][2] < -0.95
    assert main(["inspect", str(shared_mesh("spot.obj"))]) == 0
    assert "face                not found: " in capsys.readouterr().out
    assert main(["inspect", str(path), "--json", "--no-face"]) == 0
    assert "face" not in json.loads(capsys.readouterr().out)
