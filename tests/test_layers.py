"""The architecture's layers (docs/architecture.md): every ``geoface`` import, top-level or inside
a function, points down the list; the geometry core never imports torch."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "geoface"

#: rank of each top-level module or package; a module may import only lower ranks (same rank:
#: siblings that must not know each other, e.g. ddpm, texture and splat)
RANKS = {
    "errors": 0, "tol": 0.1, "rotations": 0.11, "camera": 0.12, "landmarks": 0.13, "images": 0.16, "_io": 0.15, "capture": 0.17, "_args": 0.2, "_lazy": 0.2, "progress": 0.3, "video": 0.4, "": 0.5, "_cache": 0.55,
    "mesh": 1, "synth": 2, "track": 2.2, "repair": 2.5, "param": 3, "gimage": 4, "uvmap": 5, "viz_arrays": 5.49, "viz": 5.5,
    "pipeline": 6, "dataset": 6.5, "nn": 7, "skin": 7.5, "ddpm": 8, "texture": 8, "splat": 8, "learn": 8.05,
    "avatar": 8.1, "hfm": 8.3, "thgs": 8.3, "drive": 8.4, "webview": 8.5, "cli": 9, "__main__": 10,
}
GEOMETRY_CORE = ("mesh", "repair", "param", "gimage", "uvmap")


def _module_name(path: Path, root: Path = PKG) -> tuple[str, bool]:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    is_pkg = parts[-1] == "__init__"
    return ".".join(parts[:-1] if is_pkg else parts), is_pkg


def _top(name: str) -> str:
    """The layer of a module: its top-level package (every ``geoface`` verb lives in ``cli``)."""
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else ""


def imports(path: Path, root: Path = PKG) -> list[tuple[str, int]]:
    """(absolute module name, line) of every import in ``path``, relative ones resolved."""
    mod, is_pkg = _module_name(path, root)
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
                out += [(f"{target}.{a.name}" if not node.module else target, node.lineno) for a in node.names]
            else:
                out.append((node.module or "", node.lineno))
    return out


def test_every_module_has_a_layer():
    tops = {p.stem if p.parent == PKG else p.relative_to(PKG).parts[0] for p in PKG.rglob("*.py")}
    tops = {"" if t == "__init__" else t for t in tops}
    assert tops <= set(RANKS), f"modules without a layer in this test: {sorted(tops - set(RANKS))}"


def violations(root: Path = PKG) -> list[str]:
    bad = []
    for path in sorted(root.rglob("*.py")):
        mod, _ = _module_name(path, root)
        src = _top(mod)
        for name, line in imports(path, root):
            if not name.startswith("geoface"):
                continue
            dst = _top(name)
            if dst == "__version__":
                dst = ""
            if dst != src and not RANKS[dst] < RANKS[src]:
                bad.append(f"{path.relative_to(root.parent)}:{line} ({src or 'geoface'}) imports {name}")
    return bad


def test_imports_point_down_the_layers():
    bad = violations()
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


@pytest.mark.parametrize("package", GEOMETRY_CORE)
def test_geometry_core_never_imports_torch(package):
    hits = [f"{p.relative_to(PKG.parent)}:{line}" for p in (PKG / package).rglob("*.py")
            for name, line in imports(p) if name.split(".")[0] in ("torch", "diffusers", "accelerate")]
    assert not hits, hits


def test_the_check_sees_a_violation(tmp_path):
    """The checker is not vacuous: lazy imports from splat into its siblings ddpm and texture
    (inside a function, absolute or relative) and from the geometry core up into ddpm are found."""
    root = tmp_path / "geoface"
    (root / "splat").mkdir(parents=True)
    (root / "param").mkdir()
    (root / "splat" / "x.py").write_text("def f():\n    from geoface.ddpm import model\n    from ..texture.nets import G\n"
                                         "    from geoface.nn import losses\n")
    (root / "param" / "y.py").write_text("import numpy\nfrom .. import ddpm\n")
    assert violations(root) == ["geoface/param/y.py:2 (param) imports geoface.ddpm",
                                "geoface/splat/x.py:2 (splat) imports geoface.ddpm",
                                "geoface/splat/x.py:3 (splat) imports geoface.texture.nets"]


def module_graph(root: Path = PKG) -> dict[str, set[str]]:
    """Module → the geoface modules it imports (packages' ``__init__`` included, lazy imports too)."""
    files = {_module_name(p, root)[0]: p for p in root.rglob("*.py")}
    graph = {}
    for mod, path in files.items():
        deps = set()
        for name, _ in imports(path, root):
            while name and name not in files:  # "geoface.nn.losses.dssim" -> "geoface.nn.losses"
                name = name.rpartition(".")[0]
            if name and name != mod and not mod.startswith(name + "."):  # a module's own package is no cycle
                deps.add(name)
        graph[mod] = deps
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Import cycles between modules (Tarjan's strongly connected components of size > 1)."""
    index, low, stack, on, out, n = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = n[0]
        n[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles_between_modules():
    found = cycles(module_graph())
    assert not found, f"modules importing each other: {found}"


def test_cycle_finder_finds_one():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_modules_stay_small():
    """One idea per module, a few hundred lines (docs/architecture.md): none grows past 450."""
    big = {str(p.relative_to(PKG)): n for p in PKG.rglob("*.py")
           if (n := len(p.read_text(encoding="utf-8").splitlines())) > 450}
    assert not big, f"modules over 450 lines (split them by concern): {big}"


def private_imports(root: Path = PKG) -> list[str]:
    """``from X import _name`` anywhere in the package, where ``_name`` is not a submodule: a name
    another module needs is public (no leading underscore) in the module that defines it."""
    bad = []
    for path in sorted(root.rglob("*.py")):
        mod, is_pkg = _module_name(path, root)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for a in node.names:
                if not a.name.startswith("_") or a.name.startswith("__"):
                    continue
                sub = root.parent.joinpath(*target.split("."), a.name)
                if sub.with_suffix(".py").is_file() or (sub / "__init__.py").is_file():
                    continue  # a private submodule of the package, e.g. ``from . import _native``
                bad.append(f"{path.relative_to(root.parent)}:{node.lineno} imports {target}.{a.name}")
    return bad


def test_no_module_imports_another_modules_private_name():
    bad = private_imports()
    assert not bad, "private names imported across modules (make them public where defined):\n" + "\n".join(bad)


def test_the_private_name_check_sees_one(tmp_path):
    root = tmp_path / "geoface"
    (root / "a").mkdir(parents=True)
    (root / "a" / "x.py").write_text("def _h():\n    pass\n")
    (root / "a" / "_sub.py").write_text("")
    (root / "a" / "y.py").write_text("def f():\n    from .x import _h\n    from . import _sub\n    from geoface.a.x import __doc__\n")
    assert private_imports(root) == ["geoface/a/y.py:2 imports geoface.a.x._h"]


def test_lazy_exports_refuse_a_name_its_own_module_shadows():
    """``from geoface.nn import render_mesh`` returned the module ``render_mesh.py`` once it had
    been imported; lazy_exports refuses such a table, and every package's table imports."""
    import importlib

    from geoface._lazy import lazy_exports

    with pytest.raises(ImportError, match="render_mesh"):
        lazy_exports("geoface.nn", {"render_mesh": "render_mesh"})
    for pkg in ("geoface", "geoface.nn", "geoface.splat", "geoface.ddpm", "geoface.texture", "geoface.skin"):
        importlib.import_module(pkg)
    from geoface.nn import mesh_render, render_mesh

    assert callable(render_mesh) and render_mesh is mesh_render.render_mesh
