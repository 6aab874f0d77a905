"""The README's and the guides' commands are real: every ``geoface ...`` line in their shell
blocks parses with the command's own parser (verbs, flags, value ranges), and every Python block
compiles."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def blocks(path: Path, langs: tuple[str, ...]) -> list[tuple[int, str]]:
    """(first line number, text) of the fenced blocks in ``path`` whose language is in ``langs``."""
    out, cur, start, lang = [], None, 0, None
    for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        m = re.match(r"^```(\w*)", line)
        if m and cur is None:
            cur, start, lang = [], k + 1, m.group(1)
        elif line.startswith("```") and cur is not None:
            if lang in langs:
                out.append((start, "\n".join(cur)))
            cur = None
        elif cur is not None:
            cur.append(line)
    return out


def geoface_commands(path: Path) -> list[tuple[int, list[str]]]:
    cmds = []
    for start, text in blocks(path, ("sh", "bash", "")):
        for k, line in enumerate(text.splitlines()):
            if not line.lstrip().startswith(("geoface", "accelerate")):
                continue  # prose in a plain block (a tree, a log) need not be shell
            words = shlex.split(line, comments=True)
            if words[:1] == ["accelerate"] and "geoface" in words:  # accelerate launch -m geoface ...
                words = words[words.index("geoface"):]
            if words[:1] != ["geoface"]:
                continue
            # "[--flag X]" in a usage line means optional: drop the brackets' content
            words = [w for w in words if not (w.startswith("[") or w.endswith("]"))]
            cmds.append((start + k, words[1:]))
    return cmds


CASES = [(p, line, args) for p in PAGES for line, args in geoface_commands(p)]


def test_the_pages_have_commands():
    assert len(CASES) > 40 and any(p.name == "README.md" for p, _, _ in CASES)


@pytest.mark.parametrize("page,line,args", CASES, ids=[f"{p.name}:{n}" for p, n, _ in CASES])
def test_every_command_parses(page, line, args):
    from geoface.cli import build_parser

    parser = build_parser()
    try:
        ns = parser.parse_args(args)
    except SystemExit as e:  # argparse exits on unknown verbs or flags and on values out of range
        pytest.fail(f"{page.name}:{line}: `geoface {' '.join(args)}` does not parse ({e})")
    assert callable(getattr(ns, "func", None)), f"{page.name}:{line}: no command"
    assert getattr(ns, "legacy_output", None) is None, f"{page.name}:{line}: a bare output path; the pages write -o OUT"


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_python_blocks_compile(page):
    for start, text in blocks(page, ("python",)):
        try:
            compile(text, f"{page.name}:{start}", "exec")
        except SyntaxError as e:
            pytest.fail(f"{page.name}:{start + (e.lineno or 1) - 1}: {e.msg}")


def test_a_wrong_flag_is_caught():
    from geoface.cli import build_parser

    with pytest.raises(SystemExit):
        build_parser().parse_args(["convert", "a.obj", "-o", "out/", "--resolution", "64"])


def test_negative_axes_parse_without_an_equals_sign():
    from geoface.cli import build_parser

    a = build_parser().parse_args(["convert", "a.obj", "-o", "out/", "--up", "-z", "--front", "-y"])
    assert (a.up, a.front) == ("-z", "-y")
    assert build_parser().parse_args(["repair", "a.obj", "-o", "b.obj", "--up", "-x"]).up == "-x"


def _python_names(page: Path) -> list[tuple[int, str, str]]:
    """(line, module, name) of every ``from geoface... import name`` and ``geoface.name`` in the
    page's Python blocks."""
    import ast

    out = []
    for start, text in blocks(page, ("python",)):
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("geoface"):
                out += [(start + node.lineno - 1, node.module, a.name) for a in node.names]
            elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "geoface":
                out.append((start + node.lineno - 1, "geoface", node.attr))
    return out


NAMES = [(p, n, m, a) for p in PAGES for n, m, a in _python_names(p)]


@pytest.mark.parametrize("page,line,module,name", NAMES, ids=[f"{p.name}:{n}:{a}" for p, n, _, a in NAMES])
def test_python_blocks_name_what_exists(page, line, module, name):
    """Every name a page's Python imports from geoface (or reads off ``geoface.``) exists."""
    import importlib

    mod = importlib.import_module(module)
    if not hasattr(mod, name):
        try:
            importlib.import_module(f"{module}.{name}")  # a submodule
        except ImportError:
            pytest.fail(f"{page.name}:{line}: {module} has no {name!r}")


def test_the_name_check_has_names():
    assert len(NAMES) > 25 and any(a == "convert" and m == "geoface" for _, _, m, a in NAMES)
