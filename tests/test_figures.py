"""Every measured figure in README.md and the guides stands under the results file it came from.

A block of a page (a paragraph, a list item, a table) *bears a figure* when, outside code, a
number carries a unit of measurement (dB, %, ×, s, min, mm, °, GB, px, FPS, steps/s, ...). Such a
block must sit in a section — under its own heading or one above it, anywhere in that section —
that names its source:

* a path ``bench/results/...`` (a glob is allowed) that exists, or the bare name of a file under
  ``bench/results/`` in backticks (```speed.jsonl```); or
* a marker ``<!-- results: PATH[, PATH ...] -->`` naming files of the repository (for a figure
  kept beside the code that made it, e.g. ``geoface/data/mediapipe_ict.json``).

A command in a code block that writes a results file (``--out bench/results/...``) names it too.
A block whose numbers are settings, definitions or specifications, not measurements, says so
with ``<!-- settings -->``: inline in the block, or on a line of its own before it.

Every source named anywhere must exist; a figure added without one fails here.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))

UNIT = (r"(?:dB|%|×|x\b|s\b|ms\b|min\b|minutes|seconds|hours?|mm\b|°|GB|MB|GiB|MiB|px\b|steps ?/ ?s|"
        r"frames ?/ ?s|fps|FPS)")
FIGURE = re.compile(r"(?<![\w.])[-−+]?\d[\d,]*(?:\.\d+)?\s?" + UNIT)
SOURCE = re.compile(r"bench/results/[\w./*{},-]*[\w*}]|(?<=`)[\w.-]+\.jsonl?(?=`)|<!-- results: ([^>]*)-->")
SETTINGS = "<!-- settings -->"


def blocks(text: str) -> list[tuple[int, str]]:
    """(first line, text) of each heading, paragraph, list item and table; a fenced code block is
    one block of its own, marked ``CODE`` (its commands may name results files, its numbers are
    not figures)."""
    out, cur, start, fence = [], [], 0, False
    for i, line in enumerate(text.splitlines(), 1):
        if line.strip().startswith("```"):
            if cur:
                out.append((start, ("CODE\n" if fence else "") + "\n".join(cur)))
                cur = []
            fence = not fence
            start = i
            continue
        if fence:
            cur.append(line)
            continue
        item = re.match(r"\s*([-*]|\d+\.)\s", line) and not (cur and cur[0].lstrip().startswith("|"))
        if (not line.strip() or line.startswith("#") or item) and cur:
            out.append((start, "\n".join(cur)))
            cur = []
        if line.startswith("#"):
            out.append((i, line))
        elif line.strip():
            start = start if cur else i
            cur.append(line)
    if cur:
        out.append((start, "\n".join(cur)))
    return out


def sources(text: str) -> list[str]:
    out = []
    for m in SOURCE.finditer(text):
        if m.group(1) is not None:
            out += [s.strip() for s in m.group(1).split(",") if s.strip()]
        elif "/" in m.group(0) or m.group(0) in _NAMES:  # a bare name only when it is a results file
            out.append(m.group(0))
    return out


_NAMES = {f.name for f in RESULTS.rglob("*") if f.is_file()}


def exists(source: str) -> bool:
    if "/" not in source:
        return source in _NAMES
    m = re.search(r"\{([^{}]*)\}", source)  # a shell brace list: every expansion must exist
    if m:
        return all(exists(source[:m.start()] + alt + source[m.end():]) for alt in m.group(1).split(","))
    return any(ROOT.glob(source)) if "*" in source else (ROOT / source).exists()


def unbacked(page: Path) -> list[tuple[int, str]]:
    """The figure-bearing blocks of ``page`` with no source in their section (anywhere in it, or
    in a section that encloses it)."""
    found: dict[int, list[str]] = {0: []}   # sources per section (by the index of its heading)
    path, n_sections, todo, settings_next = [(0, 0)], 0, [], False  # path: (level, section) from the top
    for line, block in blocks(page.read_text()):
        if block.startswith("#"):
            level = len(block) - len(block.lstrip("#"))
            while path and path[-1][0] >= level:
                path.pop()
            n_sections += 1
            path.append((level, n_sections))
            found[n_sections] = []
            continue
        if block.strip() == SETTINGS:
            settings_next = True
            continue
        found[path[-1][1]].extend(sources(block))
        if block.startswith("CODE\n"):
            continue
        settled, settings_next = settings_next or SETTINGS in block, False
        if not settled and FIGURE.search(re.sub(r"`[^`]*`", "", block)):
            todo.append((line, block.splitlines()[0][:100], [s for _, s in path]))
    return [(line, text) for line, text, sections in todo if not any(found[s] for s in sections)]


def test_the_scan_sees_figures_and_sources():
    text = "# A\n\nIt takes 12 s (`bench/results/x.jsonl`).\n\n## B\n\nThen 3 dB.\n\n# C\n\nAnd 4 min.\n\n" \
           "<!-- settings -->\n\nA 0.3 px low-pass.\n\n# D\n\n```bash\nrun 5 s --out bench/results/y.jsonl\n```\n\n7 dB.\n" \
           "\n# E\n\n```bash\nrun it 5 s\n```\n\n8 dB.\n"
    page = ROOT / "tests" / "_figures_probe.md"
    try:
        page.write_text(text)
        assert [ln for ln, _ in unbacked(page)] == [11, 31]  # B: under A's source; C: none; D: its command's
    finally:
        page.unlink()
    assert sources("see `speed.jsonl`, `meta.json` and bench/results/a/b.jsonl <!-- results: geoface/data/x.json, y -->") == [
        "speed.jsonl", "bench/results/a/b.jsonl", "geoface/data/x.json", "y"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_figure_names_its_results_file(page):
    bad = unbacked(page)
    assert not bad, f"{page.name}: figures with no results file in their section: " + "; ".join(
        f"line {ln}: {text!r}" for ln, text in bad)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_named_results_file_exists(page):
    text = "\n".join(b for _, b in blocks(page.read_text()))
    missing = sorted({s for s in sources(text) if not exists(s)})
    assert not missing, f"{page.name} names results files that do not exist: {missing}"
