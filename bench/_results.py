"""What the benchmarks share: JSON lines to stdout and, as they come, to a results file."""
from __future__ import annotations

import json
from pathlib import Path


def emitter(out):
    """A function that prints a dict as one JSON line and appends it to ``out`` (when given) at
    once, so that an interrupted run keeps what it measured."""
    def emit(d: dict) -> dict:
        print(json.dumps(d), flush=True)
        if out:
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            with open(out, "a") as fh:
                fh.write(json.dumps(d) + "\n")
        return d

    return emit
