"""A picture of ``geoface view --web`` in headless Chromium (the one in the README).

    python data_tools/screenshot_web.py OUT.png PATH [PATH ...] [--size 1280,640] [--wait 20]

Needs Debian's chromium and chromium-driver, and selenium (the dev extra).
"""
from __future__ import annotations

import argparse
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path)
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--size", default="1280,640", help="window size W,H in pixels (1280,640)")
    ap.add_argument("--wait", type=float, default=20.0, help="seconds for the scene to arrive")
    a = ap.parse_args()
    from selenium import webdriver

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = subprocess.Popen([sys.executable, "-m", "geoface", "view", "--web", *a.paths, "--port", str(port),
                               "--idle-exit", "2", "--exit-after", "300"], stdout=subprocess.PIPE, text=True)
    for line in server.stdout:  # wait for the URL
        if "http://" in line:
            break
    opts = webdriver.ChromeOptions()
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={a.size}",
                "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"):
        opts.add_argument(arg)
    opts.binary_location = shutil.which("chromium") or shutil.which("chromium-browser") or ""
    driver = webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=shutil.which("chromedriver")))
    try:
        driver.get(f"http://127.0.0.1:{port}")
        time.sleep(a.wait)
        # the browser's own notice ("Software WebGL rendering detected": headless Chromium has no GPU)
        # is not part of the viewer: take it off the page before the picture
        driver.execute_script("document.querySelectorAll('[class*=\"Notification\"]').forEach(e => e.remove())")
        time.sleep(1.0)
        a.out.parent.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(a.out))
    finally:
        driver.quit()
    server.wait(timeout=60)
    print(f"{a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
