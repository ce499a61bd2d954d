"""Runtime of ``mask_quality`` on 32 synthetic val images (320 px) × 100 detections each.

    python benchmarks/mask_quality.py [--images 32] [--dets 100] [--runs 3]

Detections per image: its ground-truth masks through the ceiling grid at ratios 1, 2, 4 and
8, then shifted copies of those (-3..3 px) with random classes, until ``--dets``; scores
uniform. Prints one JSON line: the median seconds of ``--runs`` calls and per image.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from slimseg.data.synth import generate
from slimseg.detections import decode_rle, encode_rle
from slimseg.eval.ceiling import coarse_masks
from slimseg.eval.coco_eval import load_gt
from slimseg.eval.mask_quality import mask_quality


def detections(gt_path: Path, per_image: int, seed: int = 0) -> list[dict]:
    gt = load_gt(gt_path)
    rng = np.random.default_rng(seed)
    cats = sorted(gt.cats)
    out: list[dict] = []
    for img, info in gt.imgs.items():
        anns = gt.imgToAnns.get(img, [])
        masks = decode_rle([gt.annToRLE(a) for a in anns], (info["height"], info["width"]))
        pool = np.concatenate([coarse_masks(masks, r) for r in (1, 2, 4, 8)])
        labels = [a["category_id"] for a in anns] * 4
        picked, classes = list(pool), list(labels)
        while len(picked) < per_image and len(pool):
            k = int(rng.integers(len(pool)))
            dy, dx = (int(v) for v in rng.integers(-3, 4, 2))
            picked.append(np.roll(pool[k], (dy, dx), axis=(0, 1)))
            classes.append(labels[k] if rng.random() < 0.5 else int(rng.choice(cats)))
        rles = encode_rle(np.stack(picked[:per_image]))
        scores = rng.random(len(rles))
        out += [
            {"image_id": img, "category_id": int(c), "segmentation": r, "score": float(s)}
            for c, r, s in zip(classes, rles, scores, strict=False)
        ]
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--images", type=int, default=32)
    p.add_argument("--dets", type=int, default=100)
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        report = generate(Path(tmp) / "ds", 1, args.images, 320, seed=0, progress=False)
        gt_path = report.data_yaml.parent / "val" / "annotations.json"
        dets = detections(gt_path, args.dets)
        seconds = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            mask_quality(gt_path, dets)
            seconds.append(time.perf_counter() - t0)
    median = statistics.median(seconds)
    print(
        json.dumps(
            {
                "images": args.images,
                "detections": len(dets),
                "median_s": round(median, 3),
                "ms_per_image": round(1000 * median / args.images, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
