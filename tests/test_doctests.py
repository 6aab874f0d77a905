"""The examples in the package's docstrings run and print what they say."""
import doctest
import importlib
from pathlib import Path

import pytest

import geoface

ROOT = Path(geoface.__file__).parent
MODULES = sorted(".".join(("geoface",) + p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
                 for p in ROOT.rglob("*.py") if ">>>" in p.read_text(encoding="utf-8"))


def test_modules_with_examples_found():
    assert {"geoface.param.metrics", "geoface.synth.head", "geoface.viz"} <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write a picture write it here
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             verbose=False, report=False)
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} docstring examples failed"
