"""Regenerate tests/reference/complexity.json (params, gradients, GFLOPs of every variant)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from slimseg.eval.complexity import measure
from slimseg.models.registry import build_model, list_models

OUT = Path(__file__).resolve().parents[1] / "tests" / "reference" / "complexity.json"
NUM_CLASSES = (20, 80)
IMGSZ = 640


def main() -> int:
    table = {}
    for name in list_models():
        for nc in NUM_CLASSES:
            c = measure(build_model(name, num_classes=nc), IMGSZ)
            table[f"{name}@nc{nc}"] = c.to_dict()
            print(f"{name:20s} nc={nc:<3d} {c.params:>11,d} params {c.gflops:8.3f} GFLOPs")
    tmp = OUT.with_suffix(".tmp")
    tmp.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")
    os.replace(tmp, OUT)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
