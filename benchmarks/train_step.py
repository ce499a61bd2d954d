"""One training step on a fixed batch, slimseg vs the reference implementation, side by side.

Each toolkit's own loader makes one batch from the same procedural images (mosaic on); then
forward, loss and backward of the same model (yolov8n-seg, fresh weights) are timed for each
toolkit in turn, alternating, ``--rounds`` times. This is the part of a training step the
data pipeline cannot change: if the two networks cost the same, a full training loop can only
be faster than the reference's by the share of its step spent outside forward + loss +
backward (``benchmarks/train_throughput.py`` measures the loops).

    python benchmarks/train_step.py [--imgsz 320 640] [--rounds 3]

Needs the reference implementation (optional, benchmark-only: ``benchmarks/reference_impl.py``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import reference_impl

from slimseg.data.augment import AugmentConfig
from slimseg.data.collate import make_collate, network_input
from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.data.synth import generate
from slimseg.engine.module import ZooModule
from slimseg.models.registry import get_spec
from slimseg.utils.table import format_table


def timed_step(
    net: torch.nn.Module, images: torch.Tensor, criterion: Callable[[Any, dict], Any], batch: dict
) -> tuple[float, float, float]:
    """Seconds of forward, loss (``criterion(out, batch)[0]``, summed) and backward of one
    step; gradients are cleared afterwards."""
    t0 = time.perf_counter()
    out = net(images)
    t1 = time.perf_counter()
    value = criterion(out, batch)[0].sum()
    t2 = time.perf_counter()
    value.backward()
    t3 = time.perf_counter()
    net.zero_grad(set_to_none=True)
    return t1 - t0, t2 - t1, t3 - t2


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--imgsz", type=int, nargs="+", default=[320, 640])
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    ref = reference_impl.load()
    if ref is None:
        raise SystemExit("train_step.py compares with the reference: install it first")
    from ultralytics.cfg import get_cfg
    from ultralytics.data import build_yolo_dataset
    from ultralytics.data.utils import check_det_dataset
    from ultralytics.nn.tasks import SegmentationModel

    torch.set_num_threads(args.threads)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for imgsz in args.imgsz:
            root = Path(tmp) / str(imgsz)
            data = generate(root / "d", 4 * args.batch, 4, imgsz, 0, progress=False).data_yaml
            cfg = get_cfg(overrides={"imgsz": imgsz, "task": "segment", "close_mosaic": 0})
            info = check_det_dataset(str(reference_impl.export_yolo_data(data, root / "r")))
            rds = build_yolo_dataset(cfg, info["train"], args.batch, info, mode="train", stride=32)
            rb = rds.collate_fn([rds[i] for i in range(args.batch)])
            rb["img"] = rb["img"].float() / 255
            net_r = SegmentationModel("yolov8n-seg.yaml", nc=len(info["names"]), verbose=False)
            net_r.args = cfg
            net_r.train()
            crit_r = net_r.init_criterion()
            dm = SegDataModule(load_data_config(data), imgsz, args.batch, 0, AugmentConfig())
            dm.setup("fit")
            ob = make_collate()([dm.train_set[i] for i in range(args.batch)])
            names = load_data_config(data).names
            module = ZooModule(get_spec("yolov8n-seg", len(names)).to_dict(), {}, names)
            net_s = module.model.train()
            x = network_input(ob["images"])
            times: dict[str, list[tuple[float, float, float]]] = {"reference": [], "slimseg": []}
            for r in range(args.rounds + 1):  # round 0 warms up
                t_ref = timed_step(net_r, rb["img"], crit_r, rb)
                t_ours = timed_step(net_s, x, module.criterion, ob)
                if r:
                    times["reference"].append(t_ref)
                    times["slimseg"].append(t_ours)
            mean = {k: [sum(t[i] for t in v) / len(v) for i in range(3)] for k, v in times.items()}
            for name, (f, lo, b) in mean.items():
                rows.append([imgsz, name, 1000 * f, 1000 * lo, 1000 * b, 1000 * (f + lo + b)])
            ratio = sum(mean["reference"]) / sum(mean["slimseg"])
            rows.append([imgsz, "reference / slimseg", "", "", "", f"{ratio:.2f}"])
    print(
        f"\nyolov8n-seg, batch {args.batch}, {args.threads} threads, CPU, one batch from each "
        f"toolkit's loader; mean of {args.rounds} alternating rounds, ms"
    )
    print(format_table(["imgsz", "toolkit", "forward", "loss", "backward", "step"], rows))


if __name__ == "__main__":
    main()
