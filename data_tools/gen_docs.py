"""Generate the parts of the documentation site that come from the code: the landing page (from
the README), the changelog and licence, the command-line reference (every verb's ``--help``) and one API page per public
module (rendered by mkdocstrings from the docstrings).  ``make docs`` runs it before ``mkdocs
build``; the generated files are not committed.

    python data_tools/gen_docs.py
"""
from __future__ import annotations

import argparse
import pkgutil
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DOCS = ROOT / "docs"

#: the public modules, one API page each (private ones, ``_*``, and command-line glue are left out)
SKIP = re.compile(r"(^|\.)_|\.cli(\.|$)|_cli$|^geoface\.__main__$")


def public_modules() -> list[str]:
    import geoface

    names = ["geoface"]
    for m in pkgutil.walk_packages(geoface.__path__, "geoface."):
        if not SKIP.search(m.name):
            names.append(m.name)
    return sorted(names)


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
        write(api / f"{m}.md", f"# `{m}`\n\n::: {m}\n")
    write(api / "index.md", "# API reference\n\n" + "\n".join(f"* [`{m}`]({m}.md)" for m in mods) + "\n")
    print(f"docs: index, cli_reference, {len(mods)} API pages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
