"""`geoface view --web` in a real browser: headless Chromium (Debian's chromium and
chromium-driver, which `make install` sets up) opens the page the command serves, and the
screenshot must show the object — drawn pixels in the middle of the canvas, in its colours.
The server stops by itself once the browser has left."""
from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser", reason="the web viewer needs viser (pip install 'geoface[web]')")
webdriver = pytest.importorskip("selenium.webdriver", reason="the browser test drives Chromium with selenium")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")
if not (CHROMIUM and DRIVER):
    pytest.skip("needs Debian's chromium and chromium-driver (make install sets them up as root)", allow_module_level=True)

W, H = 1280, 720  # the objects sit in the middle; viser's control panel covers the right 340 pixels


@pytest.fixture
def browser(monkeypatch):
    import tempfile

    own = tempfile.mkdtemp(prefix="gf_chrome_")  # short: Chromium's lock socket lives there (a path of at most 107 bytes)
    monkeypatch.setenv("TMPDIR", own)  # so that its profile and lock folders are removed with the test's, not left in /tmp
    opts = webdriver.ChromeOptions()
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={W},{H}",
              "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"):
        opts.add_argument(a)
    opts.binary_location = CHROMIUM
    d = webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=DRIVER))
    d.set_page_load_timeout(60)
    yield d
    try:
        d.quit()
    except Exception:  # noqa: BLE001 — already closed by the test
        pass
    shutil.rmtree(own, ignore_errors=True)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(*paths):
    """Start `geoface view --web`; return (process, url) once it prints the URL."""
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "geoface", "view", "--web", *map(str, paths), "--port", str(port),
                             "--exit-after", "240", "--idle-exit", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    got = threading.Event()

    def read():
        for line in proc.stdout:
            lines.append(line)
            if "http://" in line:
                got.set()

    threading.Thread(target=read, daemon=True).start()
    if not got.wait(120):
        proc.kill()
        pytest.fail("no URL from geoface view --web:\n" + "".join(lines))
    url = next(w for ln in lines for w in ln.split() if w.startswith("http://"))
    assert url == f"http://127.0.0.1:{port}"
    return proc, url, lines


def _look(browser, url, ok, timeout=90.0) -> np.ndarray:
    """Open ``url`` and take screenshots until ``ok(canvas)`` holds (the scene has arrived)."""
    import cv2

    from selenium.common.exceptions import TimeoutException

    browser.get(url)
    t0 = time.monotonic()
    while True:
        try:
            png = browser.get_screenshot_as_png()
        except TimeoutException:  # the renderer is busy drawing (software WebGL on a loaded machine)
            if time.monotonic() - t0 > timeout:
                raise
            continue
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1].astype(int)
        canvas = img
        if ok(canvas) or time.monotonic() - t0 > timeout:
            return canvas
        time.sleep(0.25)


def _centre(c, frac=0.4):
    h, w = c.shape[:2]
    return c[int(h * (1 - frac) / 2): int(h * (1 + frac) / 2), int(w * (1 - frac) / 2): int(w * (1 + frac) / 2)]


def _drawn(c):
    return (np.abs(c - c[2, 2]).sum(-1) > 30)  # differs from the background (top-left corner)


def _finish(proc, browser, lines):
    browser.quit()  # the browser leaves: the server stops by itself (--idle-exit 1)
    try:
        assert proc.wait(timeout=60) == 0, "".join(lines)
    finally:
        if proc.poll() is None:
            proc.kill()


def test_web_view_of_a_coloured_head(browser, tmp_path):
    from geoface.mesh.io import Mesh, save_mesh
    from geoface.synth.ict import ict_head, load_ict_model

    head = ict_head(load_ict_model(), seed=1)
    colors = np.tile([0.95, 0.45, 0.05, 1.0], (len(head.V), 1))  # orange
    path = tmp_path / "head.ply"
    save_mesh(path, Mesh(head.V, head.F, colors=colors))
    proc, url, lines = _serve(path)

    def orange(c):
        m = _centre(c)
        return (m[..., 0] > m[..., 2] + 60) & (m[..., 0] > 80)

    canvas = _look(browser, url, lambda c: orange(c).mean() > 0.08)
    share = orange(canvas).mean()
    _finish(proc, browser, lines)
    assert share > 0.08, f"the head is not drawn in its colour: {share:.3f} of the centre is orange"


@pytest.mark.parametrize("how", ["texture", "vertex colours"])
def test_a_surface_shows_its_colour_at_its_brightness(browser, tmp_path, how):
    """A head textured (or vertex-coloured) in one skin tone shows that tone where it faces the
    camera: each channel within 12% of the colour, the hue kept (it was drawn at half brightness,
    as a metal, and vertex colours lighter and greyer than they are)."""
    from geoface.mesh.io import Mesh, save_mesh
    from geoface.synth.ict import ict_head, load_ict_model

    head = ict_head(load_ict_model(), seed=1)
    rgb = np.array([170, 120, 90])
    if how == "texture":
        tex = np.zeros((64, 64, 3), np.uint8)
        tex[:] = rgb
        path = tmp_path / "head.obj"
        save_mesh(path, Mesh(head.V, head.F, UV=head.UV, FUV=head.FUV, texture=tex))
    else:
        path = tmp_path / "head.ply"
        save_mesh(path, Mesh(head.V, head.F, colors=np.tile([*(rgb / 255.0), 1.0], (len(head.V), 1))))
    proc, url, lines = _serve(path)

    def level(c):
        return np.median(_centre(c, 0.15).reshape(-1, 3), axis=0)

    canvas = _look(browser, url, lambda c: _drawn(_centre(c, 0.3)).mean() > 0.2 and np.all(np.abs(level(c) - rgb) < 0.12 * rgb))
    got = level(canvas)
    _finish(proc, browser, lines)
    assert np.all(np.abs(got - rgb) < 0.12 * rgb), f"the face shows {got}, its colour is {rgb}"


def test_the_page_as_one_file_opens_from_disk(browser, tmp_path):
    """`view --html` writes the scene as one page that a browser opens from disk, no server:
    the head in its colour where it faces the camera (what a notebook's inline view shows)."""
    from geoface.cli import main
    from geoface.mesh.io import Mesh, save_mesh
    from geoface.synth.ict import ict_head, load_ict_model

    head = ict_head(load_ict_model(), seed=1)
    path = tmp_path / "head.ply"
    save_mesh(path, Mesh(head.V, head.F, colors=np.tile([0.95, 0.45, 0.05, 1.0], (len(head.V), 1))))
    page = tmp_path / "page.html"
    assert main(["view", str(path), "--html", str(page), "-q"]) == 0
    import re

    text = page.read_text(encoding="utf-8")
    assert page.stat().st_size > 100_000 and not re.search(r"<script[^>]+src=\"(https?:)?//", text)  # nothing fetched

    def orange(c):
        m = _centre(c)
        return (m[..., 0] > m[..., 2] + 60) & (m[..., 0] > 80)

    canvas = _look(browser, page.as_uri(), lambda c: orange(c).mean() > 0.08)
    browser.quit()
    assert orange(canvas).mean() > 0.08, orange(canvas).mean()


def test_a_file_name_with_html_is_shown_as_text(browser, tmp_path):
    """A mesh named with HTML (an <img> whose onerror runs script, an iframe) shows its name as
    characters: no element of the name exists in the page and its script never runs."""
    name = '<img src=x id=gfimg onerror="window.__gf=1"><iframe id=gfif>[l](javascript:x).obj'
    path = tmp_path / name
    shutil.copy(Path(__file__).parent / "data" / "meshes" / "spot.obj", path)
    proc, url, lines = _serve(path)
    browser.get(url)
    deadline, text = time.monotonic() + 90, ""
    while time.monotonic() < deadline:
        text = browser.execute_script("return document.body ? document.body.innerText : ''") or ""
        if "onerror" in text:
            break
        time.sleep(1.0)
    found = browser.execute_script(
        "return [document.querySelectorAll('#gfimg, img[src=\"x\"], #gfif, iframe').length,"
        " window.__gf === 1, document.querySelectorAll('a[href^=\"javascript\"]').length]")
    _finish(proc, browser, lines)
    assert "<img src=x" in text and "[l](javascript:x).obj" in text, f"the name is not shown as text: {text[:400]!r}"
    assert found == [0, False, 0], f"elements or script from the file name in the page: {found}"


def test_web_view_of_a_geometry_image_folder(browser, tmp_path):
    from tests.ddpm.conftest import make_gimage_dataset

    root = make_gimage_dataset(tmp_path / "gi", n_items=1, N=16)
    proc, url, lines = _serve(root / "head_000" / "aug0")

    def saturated(c):  # the position image: every hue; the surface: grey
        m = _centre(c, 0.5)
        return (m.max(-1) - m.min(-1)) > 90

    canvas = _look(browser, url, lambda c: saturated(c).mean() > 0.03 and _drawn(_centre(c, 0.5)).mean() > 0.1)
    sat, drawn = saturated(canvas).mean(), _drawn(_centre(canvas, 0.5)).mean()
    _finish(proc, browser, lines)
    assert sat > 0.03 and drawn > 0.1, (sat, drawn)


def test_geometry_image_tiles_stand_upright(browser, tmp_path):
    """The image tiles are shown as the PNGs are (row 0 at the top): a red marker in the
    position image's top-left corner and a blue one in its bottom-right appear top-left and
    bottom-right of each other in the page."""
    import cv2

    from tests.ddpm.conftest import make_gimage_dataset

    root = make_gimage_dataset(tmp_path / "gi", n_items=1, N=16)
    folder = root / "head_000" / "aug0"
    pos = cv2.imread(str(folder / "position.png"), cv2.IMREAD_UNCHANGED)  # BGR, 16-bit
    pos[:4, :4] = (0, 0, 65535)  # red
    pos[-4:, -4:] = (65535, 0, 0)  # blue
    cv2.imwrite(str(folder / "position.png"), pos)
    mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE)
    mask[:4, :4] = mask[-4:, -4:] = 255
    cv2.imwrite(str(folder / "mask.png"), mask)
    proc, url, lines = _serve(folder)

    def markers(c):
        red = (c[..., 0] > 180) & (c[..., 1] < 70) & (c[..., 2] < 70)
        blue = (c[..., 2] > 180) & (c[..., 0] < 70) & (c[..., 1] < 70)
        return red, blue

    canvas = _look(browser, url, lambda c: all(m.sum() > 20 for m in markers(c)))
    _finish(proc, browser, lines)
    red, blue = markers(canvas)
    assert red.sum() > 20 and blue.sum() > 20, (red.sum(), blue.sum())
    (ry, rx), (by, bx) = (np.argwhere(m).mean(0) for m in (red, blue))
    assert ry < by and rx < bx, f"the tile is not upright: red marker at {(ry, rx)}, blue at {(by, bx)}"


def test_web_view_of_gaussian_splats(browser, tmp_path):
    from geoface.splat.gaussians import Gaussians
    from geoface.splat.ply import save_ply
    from geoface.synth.ict import ict_head, load_ict_model

    head = ict_head(load_ict_model(), seed=2)
    g = Gaussians.from_mesh(head.V, head.F, np.tile([0.1, 0.85, 0.2], (len(head.V), 1)), opacity=0.9)
    keep = slice(None, None, 4)  # a quarter of them, twice as wide: lighter for software WebGL
    g = Gaussians(g.means[keep].detach(), g.log_scales[keep].detach() + np.log(2.0), g.quats[keep].detach(),
                  g.opacity_logits[keep].detach(), g.colors[keep].detach())
    path = tmp_path / "head_gs.ply"
    save_ply(g, path)
    proc, url, lines = _serve(path)

    def green(c):
        m = _centre(c)
        return (m[..., 1] > m[..., 0] + 50) & (m[..., 1] > m[..., 2] + 50)

    canvas = _look(browser, url, lambda c: green(c).mean() > 0.08)
    share = green(canvas).mean()
    _finish(proc, browser, lines)
    assert share > 0.08, f"the splats are not drawn in their colour: {share:.3f} of the centre is green"


def test_web_view_refuses_bad_input(tmp_path, capsys):
    from geoface.cli import main

    (tmp_path / "empty").mkdir()
    assert main(["view", "--web", str(tmp_path / "empty"), "--port", str(_free_port())]) == 2
    assert "neither a geometry image" in capsys.readouterr().err
    assert main(["view", "--web", str(Path(__file__).parent / "data" / "meshes" / "spot.obj"), "--drive",
                 str(tmp_path / "x.wav")]) == 2
    assert "drives an avatar" in capsys.readouterr().err
    assert main(["view", str(Path(__file__).parent / "data" / "meshes" / "spot.obj"), "--drive", "x.wav"]) == 2
    assert "belong to --web" in capsys.readouterr().err


def test_the_notebook_view_is_quiet(tmp_path, capsys):
    """``WebView(...).notebook()`` embeds the page inline without a warning or viser's banner
    (a stored notebook would keep both, with a URL that is dead once the kernel stops)."""
    pytest.importorskip("IPython")
    import warnings

    from geoface.webview import WebView

    view = WebView([Path(__file__).parent / "data" / "meshes" / "spot.obj"], port=0, quiet=True)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            out = view.notebook(height=300)
    finally:
        view.stop()
    html = out.data
    assert html.startswith("<div><iframe srcdoc=") and "height: 300px" in html and len(html) > 100_000
    captured = capsys.readouterr()
    assert "viser" not in captured.out + captured.err and "http://" not in captured.out + captured.err
