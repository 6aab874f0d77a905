"""The documentation site builds offline with no warnings (mkdocs --strict): every guide, the
command-line reference and one API page per package of the public API, grouped by layer and
rendered from the docstrings."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_site_builds_with_no_warnings(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    shutil.copytree(ROOT / "docs", tmp_path / "docs", ignore=shutil.ignore_patterns("api", "index.md", "cli_reference.md",
                                                                                   "changelog.md", "license.md", "citation.md"))
    cfg = (ROOT / "mkdocs.yml").read_text(encoding="utf-8").replace("paths: [.]", f"paths: [{ROOT}]")
    cfg = cfg.replace("- data_tools/", f"- {ROOT}/data_tools/")
    (tmp_path / "mkdocs.yml").write_text(cfg, encoding="utf-8")
    env = {**os.environ, "GEOFACE_QUIET": "1", "NO_MKDOCS_2_WARNING": "1"}
    subprocess.run([sys.executable, str(ROOT / "data_tools" / "gen_docs.py"), "--docs", str(tmp_path / "docs")],
                   check=True, env=env, capture_output=True)
    api = sorted(p.stem for p in (tmp_path / "docs" / "api").glob("geoface*.md"))
    # one page per package of the public API, none for internals
    assert {"geoface.mesh", "geoface.param", "geoface.ddpm", "geoface.texture", "geoface.splat", "geoface.nn"} <= set(api)
    assert not any(p in api for p in ("geoface.param.ricci", "geoface.hfm.data", "geoface.cli", "geoface._io"))
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(tmp_path / "mkdocs.yml"),
                        "-d", str(tmp_path / "site")], env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert (tmp_path / "site" / "api" / "geoface.param.html").is_file()
    page = (tmp_path / "site" / "cli_reference.html").read_text(encoding="utf-8")
    assert "geoface convert" in page and "geoface ddpm train" in page
    param = (tmp_path / "site" / "api" / "geoface.param.html").read_text(encoding="utf-8")
    assert "RicciFlowSolver" in param and "measure_preserving_map" in param and "RicciFlowSolver.solve" in param
    index = (tmp_path / "site" / "api" / "index.html").read_text(encoding="utf-8")
    layers = [index.find(f">{h}<") for h in ("Foundations", "Geometry", "Pipelines", "Pictures", "Neural consumers")]
    assert all(k > 0 for k in layers) and layers == sorted(layers), layers  # grouped by layer, in order
    # docstrings rendered: no raw reST markup in the text of any API page
    for page_html in (tmp_path / "site" / "api").glob("*.html"):
        text = re.sub(r"<[^>]+>", "", page_html.read_text(encoding="utf-8"))
        for raw in ("``", ":class:`", ":func:`", ":mod:`", ":meth:`"):
            assert raw not in text, f"{page_html.name} shows {raw!r}"
    # the site opens from disk: every page's relative links name files that exist (no folder
    # links, which a file:// browser shows as a directory listing)
    from urllib.parse import unquote

    site = tmp_path / "site"
    for html in [site / "index.html", site / "benchmarks.html", site / "api" / "geoface.param.html"]:
        for href in set(re.findall(r'href="([^"#?]+)', html.read_text(encoding="utf-8"))):
            if "://" in href or href.startswith(("mailto:", "data:", "javascript:")):
                continue
            target = (html.parent / unquote(href)).resolve()
            assert target.is_file(), f"{html.name}: link {href} is not a file on disk"
