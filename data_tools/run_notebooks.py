"""Execute notebooks top to bottom and store their outputs in place (``make notebooks``).

    python data_tools/run_notebooks.py                   # every notebook in notebooks/
    python data_tools/run_notebooks.py notebooks/03_ddpm.ipynb

The stored outputs are what a reader sees on the repository page; the test suite executes the
notebooks again at smaller sizes (tests/test_notebooks.py).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


def execute(path: Path, kernel: str = "python3", timeout: int = 900, cwd: Path | None = None):
    import nbclient
    import nbformat

    nb = nbformat.read(path, as_version=4)
    with tempfile.TemporaryDirectory() as tmp:
        nbclient.NotebookClient(nb, kernel_name=kernel, timeout=timeout,
                                resources={"metadata": {"path": str(cwd or tmp)}}).execute()
    return nb


def shrink_images(nb, max_width: int = 960, min_bytes: int = 40_000) -> int:
    """Re-encode large PNG outputs so a notebook stays small enough to review and to keep in git:
    at most ``max_width`` pixels wide, as an adaptive 256-colour palette (dithered). Returns the
    bytes saved."""
    import base64
    import io

    from PIL import Image

    saved = 0
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            data = out.get("data", {})
            if "image/png" not in data:
                continue
            raw = base64.b64decode(data["image/png"])
            if len(raw) < min_bytes:
                continue
            im = Image.open(io.BytesIO(raw)).convert("RGB")
            if im.width > max_width:
                im = im.resize((max_width, round(im.height * max_width / im.width)), Image.LANCZOS)
            buf = io.BytesIO()
            palette = im.quantize(256, method=Image.Quantize.MEDIANCUT)  # dithering needs a given palette
            im.quantize(palette=palette, dither=Image.Dither.FLOYDSTEINBERG).save(buf, format="PNG", optimize=True)
            if buf.tell() < len(raw):
                data["image/png"] = base64.b64encode(buf.getvalue()).decode("ascii")
                out.setdefault("metadata", {}).pop("image/png", None)  # the old width/height no longer hold
                saved += len(raw) - buf.tell()
    return saved


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("paths", nargs="*", type=Path, help="notebooks (default: all in notebooks/)")
    ap.add_argument("--kernel", default="python3")
    a = ap.parse_args()
    import nbformat

    os.environ.setdefault("GEOFACE_QUIET", "1")
    for p in a.paths or sorted(NOTEBOOKS.glob("*.ipynb")):
        t = time.perf_counter()
        nb = execute(p, a.kernel)
        shrink_images(nb)
        tmp = p.with_suffix(".ipynb.tmp")
        nbformat.write(nb, tmp)
        os.replace(tmp, p)
        print(f"{p.name}: executed in {time.perf_counter() - t:.0f} s, {p.stat().st_size / 1e3:.0f} kB", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
