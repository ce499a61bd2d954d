"""Training throughput (images/s) of slimseg and of the reference implementation, side by side.

For each image size, one run generates a procedural set and trains one epoch of the model on
it with each toolkit's own training loop and loader (in the main process, mosaic on, one
optimizer step per batch), alternating reference, slimseg, reference, slimseg, ... so both
see the same machine load. Images/s counts the batches after ``--warmup`` (the first ones
pay for allocator and kernel warm-up). A second table times each toolkit's training data
pipeline alone (decode, mosaic, affine, HSV, flip, collate), what one loader worker does,
after one untimed mosaic-buffer's worth of samples (both toolkits draw mosaic partners from a
buffer of recently decoded images) and without slimseg's decoded-sample cache, on a set of
its own, one buffer plus ``--loader-images`` large: every timed sample decodes its image
once, as in an epoch of a data set much larger than the buffer.

    python benchmarks/train_throughput.py [--model yolov8n-seg] [--imgsz 320 640] [--rounds 2]

Without the reference implementation installed (optional, benchmark-only: see
``benchmarks/reference_impl.py``), slimseg's figures are printed alone. No figure measured on
another machine is ever used.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import lightning as L
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import reference_impl

from slimseg.data.augment import AugmentConfig
from slimseg.data.collate import make_collate
from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.data.dataset import mosaic_buffer_size
from slimseg.data.synth import generate
from slimseg.engine.config import TrainConfig
from slimseg.engine.train import train
from slimseg.utils.table import format_table


class _ClockCallback(L.Callback):
    def __init__(self, clock: reference_impl.StepClock) -> None:
        self.clock = clock

    def on_train_batch_end(self, *args: object) -> None:
        self.clock.tick()


def slimseg_epoch(
    data_yaml: Path, model: str, imgsz: int, batch: int, threads: int, warmup: int, out: Path
) -> reference_impl.StepClock:
    """One epoch of ``slimseg train`` (CPU, loader in the main process, mosaic on)."""
    clock = reference_impl.StepClock(batch, warmup)
    cfg = TrainConfig(
        epochs=1, batch=batch, imgsz=imgsz, workers=0, threads=threads, close_mosaic=0
    )
    train(
        model,
        data_yaml,
        cfg,
        out,
        accelerator="cpu",
        progress=False,
        callbacks=[_ClockCallback(clock)],
    )
    return clock


def slimseg_loader_rate(data_yaml: Path, imgsz: int, batch: int, images: int) -> float:
    """Images/s of slimseg's training dataset + collate in this process (one worker), without
    the decoded-sample cache (a data set larger than the cache: every sample decodes its
    image, as the reference's default does)."""
    dm = SegDataModule(load_data_config(data_yaml), imgsz, batch, 0, AugmentConfig(), seed=0)
    dm.setup("fit")
    dataset = dm.train_set
    dataset.cache_bytes = 0
    warmup = mosaic_buffer_size(batch)
    return reference_impl.pipeline_rate(dataset, make_collate(), batch, warmup, images)


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="yolov8n-seg")
    ap.add_argument("--imgsz", type=int, nargs="+", default=[320, 640])
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--images", type=int, nargs="+", default=[96, 64], help="per --imgsz")
    ap.add_argument("--rounds", type=int, default=2, help="alternating runs per toolkit")
    ap.add_argument("--warmup", type=int, default=2, help="batches left out of the rate")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--loader-images", type=int, default=48)
    ap.add_argument("--no-reference", action="store_true", help="slimseg figures only")
    ap.add_argument(
        "--loader-only", action="store_true", help="only the data pipeline table (no training)"
    )
    args = ap.parse_args()
    if len(args.images) != len(args.imgsz):
        ap.error("--images needs one count per --imgsz")
    ref = None if args.no_reference else reference_impl.load()
    torch.set_num_threads(args.threads)
    train_rows, loader_rows = [], []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for imgsz, n_images in zip(args.imgsz, args.images, strict=True):
            data = generate(root / f"d{imgsz}", n_images, 8, imgsz, 0, progress=False).data_yaml
            ref_data = reference_impl.export_yolo_data(data, root / f"r{imgsz}") if ref else None
            n_loader = mosaic_buffer_size(args.batch) + args.loader_images
            ldata = generate(root / f"l{imgsz}", n_loader, 1, imgsz, 1, progress=False).data_yaml
            ref_ldata = reference_impl.export_yolo_data(ldata, root / f"rl{imgsz}") if ref else None
            rates: dict[str, list[float]] = {"reference": [], "slimseg": []}
            loader: dict[str, list[float]] = {"reference": [], "slimseg": []}
            for r in range(args.rounds):
                if not args.loader_only:
                    if ref is not None:
                        clock = reference_impl.train_epoch(
                            ref,
                            ref_data,
                            args.model,
                            imgsz,
                            args.batch,
                            args.threads,
                            args.warmup,
                            root / "ref-runs",
                        )
                        rates["reference"].append(clock.images_per_s())
                        torch.set_num_threads(args.threads)
                    clock = slimseg_epoch(
                        data,
                        args.model,
                        imgsz,
                        args.batch,
                        args.threads,
                        args.warmup,
                        root / f"run-{imgsz}-{r}",
                    )
                    rates["slimseg"].append(clock.images_per_s())
                    print(
                        f"{imgsz}px round {r + 1}: "
                        + ", ".join(f"{k} {v[-1]:.2f}" for k, v in rates.items() if v)
                        + " images/s",
                        flush=True,
                    )
                if ref is not None:
                    warmup = mosaic_buffer_size(args.batch)
                    loader["reference"].append(
                        reference_impl.loader_rate(
                            ref, ref_ldata, imgsz, args.batch, warmup, args.loader_images
                        )
                    )
                loader["slimseg"].append(
                    slimseg_loader_rate(ldata, imgsz, args.batch, args.loader_images)
                )
            for rows, measured in ((train_rows, rates), (loader_rows, loader)):
                if not measured["slimseg"]:
                    continue
                ours = measured["slimseg"]
                theirs = measured["reference"]
                ratio = f"{_mean(ours) / _mean(theirs):.2f}" if theirs else "not installed"
                rows.append(
                    [
                        imgsz,
                        " / ".join(f"{v:.2f}" for v in theirs) or "-",
                        " / ".join(f"{v:.2f}" for v in ours),
                        ratio,
                    ]
                )
    head = ["imgsz", "reference images/s", "slimseg images/s", "slimseg / reference"]
    print(
        f"\n{args.model}, batch {args.batch}, {args.threads} threads, CPU, loader in the main "
        f"process; {args.rounds} alternating runs each (ratio of the means)"
    )
    if train_rows:
        print(f"training loop (one epoch, batches after the first {args.warmup}):")
        print(format_table(head, train_rows))
    print("training data pipeline alone (one loader worker's throughput):")
    print(format_table(head, loader_rows))


if __name__ == "__main__":
    main()
