"""The guides stay guides: every capability page in docs/ is short enough to read (what it does,
an example, its results, its limits; the experiment history lives in git), and every fully
qualified name that docs/papers.md maps a paper's element to exists in the package."""
from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

MAX_LINES = 260
#: reference pages, not guides
EXEMPT = {"architecture.md", "cli.md"}
sys.path.insert(0, str(ROOT / "data_tools"))
from gen_docs import GENERATED_PAGES  # noqa: E402  (written into docs/ by make docs; git-ignored, not guides)

GENERATED = set(GENERATED_PAGES)

PAGES = sorted(p for p in DOCS.glob("*.md") if p.name not in EXEMPT | GENERATED)


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_guide_pages_are_short(page):
    n = len(page.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_LINES, f"docs/{page.name} has {n} lines (at most {MAX_LINES}): keep the guide, move history to git"


NAME = re.compile(r"`(geoface(?:\.[A-Za-z_][A-Za-z0-9_]*)+)`")
PAPERS = DOCS / "papers.md"
NAMES = sorted(set(NAME.findall(PAPERS.read_text(encoding="utf-8")))) if PAPERS.is_file() else []


def resolve(dotted: str):
    """The object ``dotted`` names: the longest importable module prefix, then attributes."""
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        modname = ".".join(parts[:k])
        try:
            obj = importlib.import_module(modname)
        except ModuleNotFoundError as e:
            # only "this module does not exist" means: try a shorter prefix
            if e.name is not None and (modname == e.name or modname.startswith(e.name + ".")):
                continue
            raise
        for attr in parts[k:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(f"no module of {dotted!r} imports")


def test_papers_page_names_code():
    assert len(NAMES) > 50, "docs/papers.md lists too few names"


@pytest.mark.parametrize("name", NAMES)
def test_papers_names_resolve(name):
    try:
        resolve(name)
    except (ImportError, AttributeError) as e:
        pytest.fail(f"docs/papers.md names `{name}`, which does not resolve ({type(e).__name__}: {e})")
