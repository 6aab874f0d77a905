"""Generate the parts of the documentation site that come from the code: the landing page (from
the README), the changelog and licence, the command-line reference (every verb's ``--help``) and one API page per public
module (rendered by mkdocstrings from the docstrings).  ``make docs`` runs it before ``mkdocs
build``; the generated files are not committed.

    python data_tools/gen_docs.py
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DOCS = ROOT / "docs"
#: the pages main() writes into docs/ (git-ignored): not guides, and not for run_guides to run
GENERATED_PAGES = ("index.md", "cli_reference.md", "changelog.md", "license.md", "citation.md")

#: the API reference, by layer (docs/architecture.md): one page per package or module, showing
#: what its ``__all__`` exports
LAYERS = [
    ("Foundations", ["geoface", "geoface.errors", "geoface.tol", "geoface.progress", "geoface.video", "geoface.images",
                     "geoface.rotations", "geoface.camera", "geoface.landmarks", "geoface.capture"]),
    ("Geometry", ["geoface.mesh", "geoface.synth", "geoface.repair", "geoface.param", "geoface.gimage", "geoface.uvmap"]),
    ("Pipelines", ["geoface.pipeline", "geoface.dataset"]),
    ("Pictures", ["geoface.viz", "geoface.webview"]),
    ("Neural consumers", ["geoface.nn", "geoface.ddpm", "geoface.texture", "geoface.skin", "geoface.splat"]),
    ("Avatars", ["geoface.track", "geoface.avatar", "geoface.hfm", "geoface.thgs", "geoface.drive"]),
]


def public_modules() -> list[str]:
    return [m for _, mods in LAYERS for m in mods]


def _summary(mod) -> str:
    doc = (mod.__doc__ or "").strip().split("\n\n")[0]
    return " ".join(doc.split())


def api_page(name: str) -> str:
    """A package's page: its docstring, then each exported name from the module that defines it
    (lazily exported names too, which a static reader cannot follow)."""
    import importlib
    import inspect

    mod = importlib.import_module(name)
    exported = getattr(mod, "__all__", None)
    out = [f"# `{name}`", ""]
    if exported is None:
        out += [f"::: {name}", ""]
        return "\n".join(out)
    out += [f"::: {name}", "    options:", "      members: false", ""]
    pages = public_modules()
    elsewhere = []
    for n in exported:
        obj = getattr(mod, n)
        if inspect.ismodule(obj) or n.startswith("_"):
            continue
        home = getattr(obj, "__module__", None) if (inspect.isclass(obj) or inspect.isfunction(obj)) else None
        if home is None or not home.startswith("geoface"):
            # a constant: documented in the module that defines it (a lazily exported one cannot be
            # read from the package), on this page unless another package's page owns that module
            home = getattr(getattr(mod, "__getattr__", None), "homes", {}).get(n, name)
            owner = max((p for p in pages if home == p or home.startswith(p + ".")), key=len, default=name)
            if owner != name:
                elsewhere.append(f"[`{n}`]({owner}.md#{home}.{n})")
                continue
            out += [f"::: {home}.{n}", "    options:", "      show_root_heading: true", "      heading_level: 2", ""]
            continue
        owner = max((p for p in pages if home == p or home.startswith(p + ".")), key=len, default=name)
        if owner != name:  # documented on the page of the package that defines it
            elsewhere.append(f"[`{n}`]({owner}.md#{home}.{obj.__qualname__})")
            continue
        out += [f"::: {home}.{obj.__qualname__}", "    options:", "      show_root_heading: true",
                "      show_root_full_path: false", "      heading_level: 2", ""]
    if elsewhere:
        out[2:2] = ["Also exported here: " + ", ".join(elsewhere) + ".", ""]
    return "\n".join(out)


def api_index() -> str:
    import importlib

    out = ["# API reference", "",
           "The public API, package by package, in the order the layers depend on each other "
           "([architecture](../architecture.md)): each page shows what the package exports "
           "(`__all__`); everything else is internal and may change.", ""]
    for layer, mods in LAYERS:
        out += [f"## {layer}", ""]
        for m in mods:
            out.append(f"* [`{m}`]({m}.md) — {_summary(importlib.import_module(m))}")
        out.append("")
    return "\n".join(out)


def write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


def landing_page() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    text = re.sub(r"\]\(docs/", "](", text)
    return (text.replace("](LICENSE)", "](license.md)").replace("](CHANGELOG.md)", "](changelog.md)")
            .replace("](CITATION.cff)", "](citation.md)"))


def cli_reference() -> str:
    from geoface.cli import build_parser

    parser = build_parser()
    out = ["# Command-line reference", "",
           "Every verb of the `geoface` command with its options, as `geoface VERB --help` prints them.",
           "Guides: [the command line](cli.md).", ""]

    def walk(p: argparse.ArgumentParser, words: list[str]):
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            out.extend([f"## `geoface {' '.join(words)}`", "", "```text", p.format_help().rstrip(), "```", ""])
            return
        for name, sp in subs[0].choices.items():
            walk(sp, words + [name])

    walk(parser, [])
    return "\n".join(out)


def main(argv=None) -> int:
    global DOCS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--docs", type=Path, default=DOCS, help="the docs folder to complete (default: docs/)")
    DOCS = ap.parse_args(argv).docs
    write(DOCS / "index.md", landing_page())
    write(DOCS / "cli_reference.md", cli_reference())
    write(DOCS / "changelog.md", (ROOT / "CHANGELOG.md").read_text(encoding="utf-8"))
    write(DOCS / "license.md", "# Licence\n\n```text\n" + (ROOT / "LICENSE").read_text(encoding="utf-8") + "```\n")
    write(DOCS / "citation.md", "# Citing geoface\n\n`CITATION.cff` (GitHub shows it as \"Cite this repository\"):\n\n"
          "```yaml\n" + (ROOT / "CITATION.cff").read_text(encoding="utf-8") + "```\n")
    api = DOCS / "api"
    mods = public_modules()
    for old in api.glob("*.md"):
        if old.stem not in mods and old.stem != "index":
            old.unlink()
    for m in mods:
        write(api / f"{m}.md", api_page(m))
    write(api / "index.md", api_index())
    print(f"docs: index, cli_reference, {len(mods)} API pages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
