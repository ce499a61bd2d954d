"""Training throughput (images/s) of a zoo model on the CPU, measured two ways in one run.

1. compute only: forward + loss + backward + optimizer step on pre-collated batches;
2. full pipeline: the same step fed by the training DataLoader (mosaic, affine, HSV, flip),
   once per ``--workers`` value (on 2 cores, loading in the main process wins: worker
   processes compete with the training threads).

    python benchmarks/train_throughput.py [--model yolov8n-seg] [--imgsz 320] [--batch 8]

The reference YOLOv8 implementation trains yolov8n-seg at 17.3 images/s on this machine kind
(320 px, batch 8, 2 threads; ANCHORS.md): the last line prints our figures against it.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import torch

from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.data.synth import generate
from slimseg.engine.criterion import build_criterion
from slimseg.models.registry import build_model

REFERENCE_IMAGES_PER_S = 17.3


def step_rate(model, criterion, batches, opt, steps: int) -> float:
    images = 0
    start = time.perf_counter()
    for i in range(steps):
        batch = batches[i % len(batches)] if isinstance(batches, list) else next(batches)
        loss, _ = criterion(model(batch["images"]), batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        images += batch["images"].shape[0]
    return images / (time.perf_counter() - start)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="yolov8n-seg")
    ap.add_argument("--imgsz", type=int, default=320)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--workers", type=int, nargs="+", default=[0, 2])
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        data = generate(Path(tmp) / "d", 256, 8, args.imgsz, 0, progress=False).data_yaml
        cfg = load_data_config(data)
        model = build_model(args.model, num_classes=len(cfg.names)).train()
        criterion = build_criterion(model)
        opt = torch.optim.SGD(model.parameters(), lr=1e-3, momentum=0.9)
        rates = {}
        for workers in args.workers:
            dm = SegDataModule(cfg, args.imgsz, args.batch, workers, seed=0)
            dm.setup("fit")
            if "compute" not in rates:
                cached = [b for _, b in zip(range(4), dm.train_dataloader(), strict=False)]
                step_rate(model, criterion, cached, opt, 3)  # warm up allocator and kernels
                rates["compute"] = step_rate(model, criterion, cached, opt, args.steps)

            def forever(dm: SegDataModule = dm) -> Iterator[dict]:
                while True:
                    yield from dm.train_dataloader()

            rates[workers] = step_rate(model, criterion, forever(), opt, args.steps)
    compute = rates.pop("compute")
    print(f"{args.model} {args.imgsz}px batch {args.batch}, {args.threads} threads")
    print(f"  compute only               {compute:6.1f} images/s")
    for workers, rate in rates.items():
        print(
            f"  full pipeline, {workers} workers  {rate:6.1f} images/s  "
            f"({rate / compute:.2f} of compute)"
        )
    best = max(rates.values())
    print(
        f"  reference implementation (ANCHORS.md): {REFERENCE_IMAGES_PER_S} images/s -> "
        f"best pipeline / reference {best / REFERENCE_IMAGES_PER_S:.2f}"
    )


if __name__ == "__main__":
    main()
