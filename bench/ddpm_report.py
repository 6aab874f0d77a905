"""Markdown tables from the DDPM evaluation's results (``bench/eval_ddpm.py``) and the data-path
bench (``bench/bench_ddpm_data.py``), for docs/ddpm.md.

    python bench/ddpm_report.py bench/results/ddpm_ict
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def rows(path: Path, case: str) -> list[dict]:
    if path.suffix == ".json":
        return [r for r in json.loads(path.read_text())["results"] if r.get("case") == case]
    return [r for r in (json.loads(x) for x in path.read_text().splitlines() if x.strip()) if r.get("case") == case]


def f(x, nd=2):
    return "–" if x is None else (f"{x:.{nd}f}" if isinstance(x, float) else str(x))


def main(root: Path) -> None:
    runs = sorted((p for p in root.glob("res*/results.json")), key=lambda p: int(p.parent.name[3:]))
    if runs:
        print("| | " + " | ".join(f"{p.parent.name[3:]}²" for p in runs) + " |")
        print("|---|" + "---|" * len(runs))
        s = [rows(p, "summary")[0] for p in runs]
        t = [rows(p, "train")[0] for p in runs]
        c = [rows(p, "classifier")[0] for p in runs]
        lines = [
            ("training steps (minutes, steps/s, 1 thread)", [f"{x['steps']} ({x['seconds'] / 60:.0f} min, {x['steps_per_second']:.2f})" for x in t]),
            ("training heads (identities)", [str(x["train_items"]) for x in t]),
            ("validity: samples / real items", [f"{x['valid_rate']:.2f} / {x['valid_rate_real']:.2f}" for x in s]),
            ("classifier accuracy on held-out identities (chance)", [f"{x['held_out_accuracy']:.2f} ({x['chance']:.2f})" for x in c]),
            ("text control: prompted expression recognised, mean over prompts", [f"{x['text_accuracy_mean']:.2f}" for x in s]),
            ("… the same expression among unconditional samples", [f"{x['unconditional_rate_mean']:.2f}" for x in s]),
            ("Vendi (renders): samples / as many real heads", [f"{x['vendi_samples_mean']:.2f} / {x['vendi_real_mean']:.2f}" for x in s]),
            ("nearest training head: samples / held-out real heads", [f"{x['nn_samples_mean']:.3f} / {x['nn_held_out_mean']:.3f}" for x in s]),
        ]
        for name, vals in lines:
            print(f"| {name} | " + " | ".join(vals) + " |")
        print()
        print("| prompt | " + " | ".join(f"{p.parent.name[3:]}²: recognised / unconditional / valid / Vendi" for p in runs) + " |")
        print("|---|" + "---|" * len(runs))
        per = [{r["expression"]: r for r in rows(p, "prompt")} for p in runs]
        for e in per[0]:
            cells = []
            for d in per:
                r = d.get(e)
                cells.append("–" if r is None else f"{r['text_accuracy']:.2f} / {r['unconditional_rate']:.2f} / {r['valid_rate']:.2f} / {r['vendi_samples']:.1f}")
            print(f"| {per[0][e]['prompt']} | " + " | ".join(cells) + " |")
        print()
    for name in ("memory.jsonl", "speed.jsonl"):
        p = root / name
        if p.is_file():
            for case in ("memory", "speed"):
                for r in rows(p, case):
                    print(json.dumps(r))


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "bench/results/ddpm_ict"))
