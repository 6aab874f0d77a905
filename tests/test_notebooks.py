"""The tutorial notebooks run top to bottom (small sizes) and show their pictures."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat", reason="notebook execution needs nbformat (pip install 'geoface[notebook]')")
nbclient = pytest.importorskip("nbclient", reason="notebook execution needs nbclient")
pytest.importorskip("ipykernel", reason="notebook execution needs ipykernel")
pytest.importorskip("pyvista", reason="the notebook renders with geoface[viz] (pyvista)")
pytest.importorskip("matplotlib", reason="the notebook plots with matplotlib")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
KERNEL = "geoface-test-python"
SMALL = {"N_VERTICES": "3000", "RES": "64", "TEXTURE_SIZE": "128", "WINDOW": "(240, 240)"}


@pytest.fixture
def this_python_kernel(tmp_path, monkeypatch):
    """A kernelspec that runs *this* interpreter (the venv), found first via JUPYTER_PATH,
    under a name no installed kernel uses, so a user's own "python3" kernel cannot stand in."""
    spec = tmp_path / "jupyter" / "kernels" / KERNEL
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "geoface tests", "language": "python",
    }))
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter"))
    monkeypatch.setenv("GEOFACE_QUIET", "1")
    (tmp_path / "tmp").mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))  # the notebooks' work folders go with the test's, not into /tmp
    return KERNEL


def _set_parameters(nb, values: dict) -> None:
    cell = next(c for c in nb.cells if c.cell_type == "code" and c.source.lstrip().startswith("# parameters"))
    src = cell.source
    for name, value in values.items():
        src, n = re.subn(rf"^{name}\s*=\s*[^#\n]*", f"{name} = {value}  ", src, flags=re.M)
        assert n == 1, f"parameter {name} not found in the parameters cell"
    cell.source = src


ALL = ["01_mesh_to_geometry_image.ipynb", "02_real_head.ipynb", "03_ddpm.ipynb", "04_splats_and_avatar.ipynb",
       "05_skin_textures.ipynb"]


def test_every_notebook_is_tested():
    assert sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")) == ALL


@pytest.mark.parametrize("name", ALL)
def test_notebook_stored_with_its_pictures(name):
    """Stored executed (``make notebooks``) so that it reads on a repository page: every code
    cell ran, in order, without errors, and the pictures are there — small enough to review."""
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert [c.execution_count for c in code] == list(range(1, len(code) + 1))
    outputs = [o for c in code for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs)
    views = [o["data"]["text/html"] for o in outputs if "<iframe srcdoc=" in "".join(o.get("data", {}).get("text/html", ""))]
    if name in ("01_mesh_to_geometry_image.ipynb", "02_real_head.ipynb"):
        assert len(views) == 1, "an inline, turnable 3D view (the web viewer, self-contained)"
    view_bytes = sum(len("".join(v)) for v in views)
    assert all(len("".join(v)) < 3_500_000 for v in views)
    assert (NOTEBOOKS / name).stat().st_size - view_bytes < 1_500_000  # the pictures and the rest
    # clean: what a reader sees carries no warning, no server banner and no path of the machine
    # that ran it
    text = "\n".join("".join(o.get("text", "")) + "".join(o.get("data", {}).get("text/plain", ""))
                      for o in outputs)
    for bad in ("Warning", "warn(", "viser", "http://", "/work/", "/home/", "/tmp/", "/root/", "site-packages"):
        assert bad not in text, f"{name}: a stored output holds {bad!r}"


def _run(name, kernel, tmp_path, params):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    for c in nb.cells:  # start from a clean notebook, as a reader re-running it would
        if c.cell_type == "code":
            c.outputs, c.execution_count = [], None
    _set_parameters(nb, params)
    nbclient.NotebookClient(nb, kernel_name=kernel, timeout=300, resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    images = [o for o in outputs if o.output_type in ("display_data", "execute_result") and "image/png" in o.get("data", {})]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    return images, text


def test_ddpm_notebook_runs(this_python_kernel, tmp_path):
    images, text = _run("03_ddpm.ipynb", this_python_kernel, tmp_path, {"HEADS": "3", "RES": "16", "STEPS": "8", "SAMPLES": "2"})
    assert len(images) >= 2  # the dataset's images, the samples
    assert "ict_0002/aug0" in text and "8 steps, loss" in text and "sample 1: valid" in text


def test_splats_and_avatar_notebook_runs(this_python_kernel, tmp_path):
    images, text = _run("04_splats_and_avatar.ipynb", this_python_kernel, tmp_path,
                        {"RES": "48", "ITERS": "20", "VERTICES": "1000", "TALK_SECONDS": "1.0", "TALK_ITERS": "10"})
    assert len(images) >= 2  # held-out views, animation frames
    assert "held-out" in text and "Gaussians" in text and "frames rendered from the audio" in text


def test_skin_textures_notebook_runs(this_python_kernel, tmp_path):
    images, text = _run("05_skin_textures.ipynb", this_python_kernel, tmp_path, {"COUNT": "2", "RES": "64", "EPOCHS": "2"})
    assert len(images) >= 3  # the sample, the losses, the reconstruction
    assert "GDE upsampled" in text and "GDE + HFDR" in text


def test_mesh_to_geometry_image_notebook_runs(this_python_kernel, tmp_path):
    nb = nbformat.read(NOTEBOOKS / "01_mesh_to_geometry_image.ipynb", as_version=4)
    for c in nb.cells:
        if c.cell_type == "code":
            c.outputs, c.execution_count = [], None
    _set_parameters(nb, SMALL)
    nb.cells.append(nbformat.v4.new_code_cell("import sys; print('KERNEL-PYTHON', sys.executable)"))
    client = nbclient.NotebookClient(nb, kernel_name=this_python_kernel, timeout=300,
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # raises CellExecutionError (with the traceback) on any error
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    images = [o for o in outputs if o.output_type in ("display_data", "execute_result") and "image/png" in o.get("data", {})]
    assert len(images) >= 7  # head, QC map, area maps, matplotlib montage, viz montage, two comparisons
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert f"KERNEL-PYTHON {sys.executable}" in text  # ran in this interpreter, not some other "python3"
    assert "is disk: True" in text and "Hausdorff" in text
    assert any("<iframe srcdoc=" in "".join(o.get("data", {}).get("text/html", "")) for o in outputs)  # the 3D view


def test_real_head_notebook_runs(this_python_kernel, tmp_path):
    nb = nbformat.read(NOTEBOOKS / "02_real_head.ipynb", as_version=4)
    for c in nb.cells:
        if c.cell_type == "code":
            c.outputs, c.execution_count = [], None
    _set_parameters(nb, {"RES": "32", "WINDOW": "(200, 200)"})
    client = nbclient.NotebookClient(nb, kernel_name=this_python_kernel, timeout=300,
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    images = [o for o in outputs if o.output_type in ("display_data", "execute_result") and "image/png" in o.get("data", {})]
    assert len(images) >= 4  # the head, position and normal, the rebuilt mesh, three expressions
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "100 identity modes, 53 expressions" in text and "flipped triangles 0" in text and "rebuilt from the images" in text
    assert any("<iframe srcdoc=" in "".join(o.get("data", {}).get("text/html", "")) for o in outputs)  # the 3D view
