"""Run the docs' "Try it" blocks as a user would and time each command.

Every fenced ``bash`` or ``python`` block that follows a line ``<!-- try-it -->`` in ``docs/*.md``
or ``README.md`` is run, line by line (a Python block as one script), in one fresh folder per page,
on the installed ``geoface``. Lines ending in ``&`` or naming ``--web`` start a server: those run
for ``--serve-seconds`` and count as passing when the server prints its address. One JSON line per
command goes to stdout (page, command, seconds, exit code); the exit code is 1 when any failed.

    python data_tools/run_guides.py                      # every page
    python data_tools/run_guides.py docs/hmd.md --keep /tmp/guides   # one page, outputs kept
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARK = "<!-- try-it -->"
FENCE = re.compile(r"^```(\w*)\s*$")


def blocks(page: Path) -> list[tuple[str, str]]:
    """(language, text) of each marked block of ``page``."""
    out, lines, i = [], page.read_text().splitlines(), 0
    while i < len(lines):
        if lines[i].strip() == MARK:
            j = i + 1
            while j < len(lines) and not lines[j].strip():
                j += 1
            m = FENCE.match(lines[j]) if j < len(lines) else None
            if not m:
                raise SystemExit(f"{page}:{i + 1}: {MARK} must be followed by a fenced block")
            k = j + 1
            while k < len(lines) and not lines[k].startswith("```"):
                k += 1
            out.append((m.group(1) or "bash", "\n".join(lines[j + 1:k])))
            i = k
        i += 1
    return out


def commands(lang: str, text: str) -> list[str]:
    if lang == "python":
        return [text]
    return [ln.split("  #")[0].rstrip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def run_one(cmd: str, lang: str, cwd: Path, serve_s: float) -> tuple[int, float, str]:
    env = dict(os.environ, GEOFACE_QUIET="1")
    t0 = time.perf_counter()
    if lang == "python":
        script = cwd / "_snippet.py"
        script.write_text(cmd + "\n")
        p = subprocess.run([sys.executable, str(script)], cwd=cwd, env=env, capture_output=True, text=True)
        return p.returncode, time.perf_counter() - t0, (p.stdout + p.stderr)[-2000:]
    if "--web" in cmd or cmd.endswith("&"):
        p = subprocess.Popen(cmd.rstrip("& "), shell=True, cwd=cwd, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, start_new_session=True)
        try:
            out, _ = p.communicate(timeout=serve_s)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, 15)
            out, _ = p.communicate()
        ok = "http://" in out
        return (0 if ok else (p.returncode or 1)), time.perf_counter() - t0, out[-2000:]
    p = subprocess.run(cmd, shell=True, cwd=cwd, env=env, capture_output=True, text=True, executable="/bin/bash")
    return p.returncode, time.perf_counter() - t0, (p.stdout + p.stderr)[-2000:]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pages", nargs="*", help="pages to run (default: README.md and docs/*.md)")
    ap.add_argument("--keep", default=None, metavar="DIR", help="run in DIR/<page>/ and keep the outputs")
    ap.add_argument("--serve-seconds", type=float, default=20.0)
    a = ap.parse_args(argv)
    from gen_docs import GENERATED_PAGES  # beside this script

    pages = [Path(p) for p in a.pages] or [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").glob("*.md")
                                                                       if p.name not in GENERATED_PAGES)]
    failed = 0
    for page in pages:
        found = blocks(page)
        if not found:
            continue
        base = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="guide_"))
        cwd = base / page.stem
        cwd.mkdir(parents=True, exist_ok=True)
        for name in ("data_tools", "bench", "tests"):  # scripts the guides call by their repository path
            if not (cwd / name).exists():
                (cwd / name).symlink_to(ROOT / name)
        total = 0.0
        for lang, text in found:
            for cmd in commands(lang, text):
                rc, sec, tail = run_one(cmd, lang, cwd, a.serve_seconds)
                total += sec
                rec = {"page": page.name, "command": cmd if lang != "python" else "python snippet",
                       "seconds": round(sec, 1), "rc": rc}
                if rc:
                    rec["output"] = tail
                    failed += 1
                print(json.dumps(rec), flush=True)
        print(json.dumps({"page": page.name, "total_seconds": round(total, 1)}), flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
