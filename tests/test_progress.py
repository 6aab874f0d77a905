import io
import sys

from geoface import progress as P


def test_progress_prints_rate_and_eta_outside_a_terminal(monkeypatch):
    buf = io.StringIO()  # not a terminal
    monkeypatch.setattr(sys, "stderr", buf)
    assert list(P.progress(range(4), "fitting", quiet=False)) == [0, 1, 2, 3]
    lines = buf.getvalue().splitlines()
    assert lines[0].startswith("fitting: step 1/4 (25%)") and "steps/s, ETA" in lines[0]
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
