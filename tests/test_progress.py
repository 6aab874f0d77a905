import io
import sys

from geoface import progress as P


def test_progress_prints_rate_and_eta_outside_a_terminal(monkeypatch):
    buf = io.StringIO()  # not a terminal
    monkeypatch.setattr(sys, "stderr", buf)
    assert list(P.progress(range(4), "fitting", quiet=False)) == [0, 1, 2, 3]
    lines = buf.getvalue().splitlines()
    assert lines[0].startswith("fitting: step 1/4 (25%)") and "steps/s, " in lines[0] and " left" in lines[0]
    assert lines[-1].startswith("fitting: step 4/4 (100%)")
    buf.truncate(0), buf.seek(0)
    assert list(P.progress((x for x in "ab"), "reading", quiet=False, unit="files")) == ["a", "b"]
    assert buf.getvalue().splitlines()[-1].startswith("reading: 2 files, ")


def test_progress_is_silent_when_quiet(monkeypatch):
    buf = io.StringIO()
    monkeypatch.setattr(sys, "stderr", buf)
    assert list(P.progress(range(3), "x", quiet=True)) == [0, 1, 2]
    monkeypatch.setattr(P, "QUIET", True)
    assert list(P.progress(range(3), "x")) == [0, 1, 2]
    assert buf.getvalue() == ""


def test_the_library_is_quiet_by_default():
    """A fresh interpreter without GEOFACE_QUIET (a real process: the library's default is read
    at import): a library call prints nothing."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "GEOFACE_QUIET"}
    code = ("from geoface.synth import procedural_head\nfrom geoface.repair import make_disk\n"
            "h = procedural_head(n_vertices=2000, seed=0)\nmake_disk(h.V, h.F)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0 and r.stdout == "" and r.stderr == "", r.stderr[-500:]

def test_the_command_shows_progress_and_q_silences_it(tmp_path, capsys, monkeypatch):
    """The command run as a user runs it (no GEOFACE_QUIET): progress on stderr; -q: none."""
    from geoface.cli import main

    monkeypatch.delenv("GEOFACE_QUIET", raising=False)
    mesh = tmp_path / "h.obj"
    assert main(["synth", "head", "-o", str(mesh), "--vertices", "2000", "-q"]) == 0
    capsys.readouterr()
    assert main(["repair", str(mesh), "-o", str(tmp_path / "d.obj")]) == 0
    assert "repairing" in capsys.readouterr().err
    assert main(["repair", str(mesh), "-o", str(tmp_path / "e.obj"), "-q"]) == 0
    assert capsys.readouterr().err == ""


def test_convert_says_little_by_default_and_the_iterations_with_v(tmp_path, capsys, caplog):
    """The command's default output is the stage lines and a one-line summary; -v adds every
    Ricci and OT iteration; the same lines reach the ``geoface`` logger (DEBUG for detail)."""
    import logging

    from geoface.cli import main

    src = tmp_path / "h.obj"
    assert main(["synth", "head", "-o", str(src), "--vertices", "3000", "-q"]) == 0
    capsys.readouterr()
    env_quiet = P.QUIET
    import os

    os.environ.pop("GEOFACE_QUIET", None)
    try:
        assert main(["convert", str(src), "-o", str(tmp_path / "a"), "--res", "32"]) == 0
        cap = capsys.readouterr()
        err = cap.err.splitlines()
        assert 1 <= len(err) <= 3 and not any("iteration" in e or "OT stage" in e for e in err), err
        assert len(cap.out.splitlines()) == 1 and "1 image set at 32x32" in cap.out and "0 flipped" in cap.out
        with caplog.at_level(logging.DEBUG, logger="geoface"):
            assert main(["convert", str(src), "-o", str(tmp_path / "b"), "--res", "32", "-v"]) == 0
        cap = capsys.readouterr()
        assert "ricci: iteration 1" in cap.err and "OT stage" in cap.err
        assert "set 0:" in cap.out  # the per-set details
        assert any(r.levelno == logging.DEBUG and "ricci: iteration" in r.getMessage() for r in caplog.records)
        assert any(r.levelno == logging.INFO and "corner set 0" in r.getMessage() for r in caplog.records)
        assert main(["convert", str(src), "-o", str(tmp_path / "c"), "--res", "32", "-q", "-v"]) == 0
        cap = capsys.readouterr()
        assert cap.err == ""
    finally:
        os.environ["GEOFACE_QUIET"] = "1"
        P.set_quiet(env_quiet)
