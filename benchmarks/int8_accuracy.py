"""INT8 accuracy of trained weights: FP32 vs each INT8 target and calibration method.

Runs ``slimseg export --int8`` (:func:`~slimseg.deploy.int8_export.export_int8`, gate at 100
points so every combination reports) for each ``--target`` × ``--method``, calibrating on
``--calib`` (DATA.yaml's val split or a folder) and scoring on ``--val`` (a held-out
DATA.yaml), and prints box and mask mAP50-95 of the FP32 graph and of each INT8 graph, the
drops, and the mask AP of one class (``--class``, default ``person``). ``--out DIR`` keeps
the files (``<target>-<method>.onnx``) for ``slimseg dynamic`` / ``slimseg val``.

    python benchmarks/int8_accuracy.py --weights runs/x/weights/best.pt --imgsz 320 \\
        --calib data/data.yaml --val heldout/data.yaml --calib-images 48
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from slimseg.deploy.int8_export import export_int8
from slimseg.deploy.int8_placement import INT8_TARGETS
from slimseg.deploy.int8_quantize import CALIB_METHODS
from slimseg.models.checkpoint import load_weights
from slimseg.utils.table import format_table


def class_mask_ap(result: dict, name: str) -> float | None:
    """Mask mAP50-95 (points) of class ``name`` in an evaluator result, if it has ground truth."""
    for row in result["per_class"]:
        if row["class"] == name and row["mask_map50_95"] is not None:
            return round(100 * row["mask_map50_95"], 2)
    return None


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", required=True)
    p.add_argument("--imgsz", type=int, default=320)
    p.add_argument("--calib", required=True, help="DATA.yaml (val split) or image folder")
    p.add_argument("--val", required=True, help="held-out DATA.yaml the mAP is measured on")
    p.add_argument("--calib-images", type=int, default=None)
    p.add_argument("--target", nargs="+", default=list(INT8_TARGETS), choices=INT8_TARGETS)
    p.add_argument("--method", nargs="+", default=list(CALIB_METHODS), choices=CALIB_METHODS)
    p.add_argument("--class", dest="cls", default="person")
    p.add_argument("--out", default=None, help="keep the INT8 files in this folder")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    model, info = load_weights(args.weights)
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.out) if args.out else Path(tmp)
        for target in args.target:
            for method in args.method:
                t0 = time.perf_counter()
                r = export_int8(
                    model,
                    folder / f"{target}-{method}.onnx",
                    args.calib,
                    (args.imgsz, args.imgsz),
                    info.names,
                    info.mobility,
                    calib_images=args.calib_images,
                    method=method,
                    max_drop=100.0,
                    val_data=args.val,
                    progress=False,
                    target=target,
                )
                if not rows:  # FP32 is the same graph every time: one row
                    fp = r.results["fp32"]
                    rows.append(_row("fp32", "-", r.map_fp32, class_mask_ap(fp, args.cls)))
                q = r.results["int8"]
                row = _row(target, method, r.map_int8, class_mask_ap(q, args.cls))
                row["drop_box"] = round(r.map_fp32["box"] - r.map_int8["box"], 2)
                row["drop_mask"] = round(r.map_fp32["mask"] - r.map_int8["mask"], 2)
                row["seconds"] = round(time.perf_counter() - t0)
                rows.append(row)
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(
        f"{args.weights} at {args.imgsz} px; calibrated on {args.calib}, scored on {args.val}; "
        f"mAP50-95 in points; '{args.cls} mask' = that class's mask mAP50-95"
    )
    headers = ["graph", "calibration", "box", "mask", f"{args.cls} mask", "box drop", "mask drop"]
    table = [
        [r["graph"], r["method"], r["box"], r["mask"], r["cls_mask"]]
        + [r.get("drop_box", "-"), r.get("drop_mask", "-")]
        for r in rows
    ]
    print(format_table(headers, table, markdown=True))


def _row(graph: str, method: str, maps: dict[str, float], cls_mask: float | None) -> dict:
    return {
        "graph": graph,
        "method": method,
        "box": round(maps["box"], 2),
        "mask": round(maps["mask"], 2),
        "cls_mask": "-" if cls_mask is None else cls_mask,
    }


if __name__ == "__main__":
    main()
