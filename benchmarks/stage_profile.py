"""Where a training step and a validation image spend their time, stage by stage.

Training (per step of ``--batch`` images, loader in the main process, mosaic on): data
decode, mosaic, letterbox, affine, HSV, flip, boxes from masks, collate, forward, assigner,
loss (without the assigner), backward, optimizer, EMA. Validation (per image): network,
NMS, mask assembly (input and frame resolution), RLE encoding, COCOeval (total / images).

    python benchmarks/stage_profile.py --data DATA.yaml [--weights best.pt] [--imgsz 320]

Training samples are drawn as the training loader draws them (mosaic partners from the
buffer of recently decoded samples, filled before the clock starts) without the decoded-sample
cache: the steady state of a data set larger than the cache.
Without ``--weights`` the model is freshly initialised, whose validation post-processing is
not representative (its scores are near the threshold): pass a trained model for that part.
Every stage runs the project's own functions; only the clock around them is added here.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch

import slimseg.losses.yolov8_seg as loss_mod
from slimseg.data.augment import AugmentConfig, masks_to_boxes
from slimseg.data.collate import make_collate, network_input
from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.data.mosaic import mosaic4
from slimseg.data.sample import Sample
from slimseg.detections import encode_rle
from slimseg.engine.config import TrainConfig
from slimseg.engine.ema import ModelEMA
from slimseg.engine.module import ZooModule
from slimseg.eval import postprocess
from slimseg.eval.coco_eval import CocoEvaluator
from slimseg.models.checkpoint import load_weights
from slimseg.models.registry import get_spec
from slimseg.ops.nms import non_max_suppression
from slimseg.utils.table import format_table

# functions of slimseg.eval.postprocess timed as validation stages (module attribute → label);
# the rest of building the frame detections (mask assembly on windows, boxes to the frame)
# is reported as "mask assembly + boxes"
POSTPROCESS_STEPS = {"window_rles": "RLE encoding (windows)"}


class Stages:
    """Accumulated seconds per stage name, in first-seen order."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    @contextmanager
    def time(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - start

    def wrap(self, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.time(name):
                return fn(*args, **kwargs)

        return timed


def train_sample(ds: Any, index: int, rng: np.random.Generator, st: Stages) -> Sample:
    """``ZooDataset.__getitem__`` (train) with a clock around each step."""
    aug = ds.augment
    with st.time("data decode"):  # the sources of a mosaic come from the partner buffer
        if ds.mosaic_enabled and rng.random() < aug.mosaic:
            parts = ds.mosaic_sources(index)
        else:
            parts = [ds.base[index]]
    if len(parts) == 4:
        with st.time("mosaic"):
            sample = mosaic4(parts, ds.imgsz, rng)
    else:
        sample = parts[0]
    h, w = sample.image.shape[:2]
    image = sample.image
    masks = sample.masks if len(sample.masks) else np.zeros((1, h, w), np.uint8)
    names = ("letterbox", "affine", "hsv", "flip")
    for name, t in zip(names, ds.transform.transforms, strict=True):
        with st.time(name):
            out = t(image=image, masks=masks)
        image, masks = out["image"], np.asarray(out["masks"], np.uint8)
    with st.time("boxes from masks"):
        masks = masks[: len(sample.masks)]
        keep = masks.sum(axis=(1, 2)) >= max(aug.min_area, 1)
        masks = masks[keep]
        boxes = masks_to_boxes(masks)
    return Sample(image, boxes, sample.classes[keep], masks, sample.image_id, sample.path, {})


def profile_train(data_yaml: Path, model: str, imgsz: int, batch: int, steps: int) -> Stages:
    cfg = load_data_config(data_yaml)
    dm = SegDataModule(cfg, imgsz, batch, 0, AugmentConfig(), seed=0)
    dm.setup("fit")
    ds = dm.train_set
    # the steady state of a data set larger than the decoded-sample cache: no cache, and a
    # partner buffer filled (from the far end of the set) before the timed samples
    ds.cache_bytes = 0
    for i in range(ds.buffer_size):
        ds.mosaic_sources(len(ds) - 1 - i)
    spec = get_spec(model, len(cfg.names))
    tcfg = TrainConfig(imgsz=imgsz, batch=batch, workers=0)
    module = ZooModule(spec.to_dict(), tcfg.__dict__, list(cfg.names))
    net = module.model.train()
    opt = module.configure_optimizers()
    ema = ModelEMA(net, tcfg.ema_decay)
    collate = make_collate()
    rng = np.random.default_rng(0)
    original = loss_mod.task_aligned_assign
    st, warm = Stages(), Stages()
    try:
        for step in range(steps + 1):  # step 0 warms up and is not counted
            s = warm if step == 0 else st
            loss_mod.task_aligned_assign = s.wrap("assigner", original)
            samples = [train_sample(ds, (step * batch + k) % len(ds), rng, s) for k in range(batch)]
            with s.time("collate"):
                b = collate(samples)
            with s.time("forward"):
                raw = net(network_input(b["images"]))
            start = time.perf_counter()
            before = s.seconds["assigner"]
            loss, _ = module.criterion(raw, b)
            s.seconds["loss (no assigner)"] += (
                time.perf_counter() - start - (s.seconds["assigner"] - before)
            )
            with s.time("backward"):
                opt.zero_grad(set_to_none=True)
                loss.backward()
            with s.time("optimizer (clip + step)"):
                torch.nn.utils.clip_grad_norm_(net.parameters(), tcfg.grad_clip)
                opt.step()
            with s.time("EMA"):
                ema.update(net)
    finally:
        loss_mod.task_aligned_assign = original
    return st


def profile_val(
    data_yaml: Path, model: str, weights: Path | None, imgsz: int, batch: int, images: int
) -> tuple[Stages, int, dict]:
    cfg = load_data_config(data_yaml)
    dm = SegDataModule(cfg, imgsz, batch, 0, seed=0)
    dm.setup("validate")
    if weights is not None:
        net, _ = load_weights(weights)
    else:
        spec = get_spec(model, len(cfg.names))
        net = ZooModule(spec.to_dict(), {}, list(cfg.names)).model
    net.eval()
    evaluator = CocoEvaluator.from_dataset(dm.val_set.base)
    st, n = Stages(), 0
    tcfg = TrainConfig()
    patched = {name: getattr(postprocess, name) for name in POSTPROCESS_STEPS}
    for name, fn in patched.items():
        setattr(postprocess, name, st.wrap(POSTPROCESS_STEPS[name], fn))
    for b in dm.val_dataloader():
        if n >= images:
            break
        with torch.no_grad():
            with st.time("network"):
                pred, proto = net(network_input(b["images"]))
            with st.time("NMS"):
                dets = non_max_suppression(pred, net.num_classes, tcfg.conf, tcfg.iou, tcfg.max_det)
            with st.time("frame detections (all)"):
                frames = postprocess.batch_to_frame_detections(
                    dets, proto, b["meta"], rle=True, mask_limit=postprocess.COCO_MAX_DETS
                )
        evaluator.update(b["image_ids"], frames)
        n += len(frames)
    for name, fn in patched.items():
        setattr(postprocess, name, fn)
    frames_total = st.seconds.pop("frame detections (all)")
    st.seconds["mask assembly + boxes"] = frames_total - sum(
        st.seconds[v] for v in POSTPROCESS_STEPS.values()
    )
    with st.time("COCOeval (bbox + segm)"):
        metrics = evaluator.summarize()
    return st, n, metrics


def compare_postprocess(
    data_yaml: Path, model: str, weights: Path | None, imgsz: int, batch: int, images: int
) -> tuple[float, float, int, int]:
    """Frame masks as RLEs two ways on the same NMS output, alternating per batch: every
    mask assembled on the full frame and encoded by pycocotools (the previous validation
    path), and the window RLEs limited to ``COCO_MAX_DETS`` per class (today's). Returns
    seconds of each, images, and masks skipped; fails if a kept RLE differs."""
    cfg = load_data_config(data_yaml)
    dm = SegDataModule(cfg, imgsz, batch, 0, seed=0)
    dm.setup("validate")
    net = load_weights(weights)[0] if weights is not None else None
    if net is None:
        spec = get_spec(model, len(cfg.names))
        net = ZooModule(spec.to_dict(), {}, list(cfg.names)).model
    net.eval()
    tcfg = TrainConfig()
    dense_s = window_s = 0.0
    n = skipped = 0
    for b in dm.val_dataloader():
        if n >= images:
            break
        with torch.no_grad():
            pred, proto = net(network_input(b["images"]))
            dets = non_max_suppression(pred, net.num_classes, tcfg.conf, tcfg.iou, tcfg.max_det)
            for d, pr, meta in zip(dets, proto, b["meta"], strict=True):
                t0 = time.perf_counter()
                full = encode_rle(postprocess.to_frame_detections(d, pr, meta).masks)
                t1 = time.perf_counter()
                win = postprocess.to_frame_detections(
                    d, pr, meta, rle=True, mask_limit=postprocess.COCO_MAX_DETS
                ).rles
                t2 = time.perf_counter()
                dense_s, window_s = dense_s + t1 - t0, window_s + t2 - t1
                if any(w is not None and w != f for w, f in zip(win, full, strict=True)):
                    raise RuntimeError("window RLEs differ from the full-frame ones")
                skipped += sum(w is None for w in win)
                n += 1
    return dense_s, window_s, n, skipped


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--model", default="yolov8n-seg")
    ap.add_argument("--weights", type=Path, default=None, help="trained weights for val")
    ap.add_argument("--imgsz", type=int, default=320)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--val-images", type=int, default=48)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--skip-train", action="store_true")
    ap.add_argument("--skip-val", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    print(f"{args.model} {args.imgsz}px batch {args.batch}, {args.threads} threads, CPU")
    if not args.skip_train:
        st = profile_train(args.data, args.model, args.imgsz, args.batch, args.steps)
        total = sum(st.seconds.values())
        network = sum(st.seconds[k] for k in ("forward", "backward"))
        rows = [[k, 1000 * v / args.steps, f"{100 * v / total:.1f}"] for k, v in st.seconds.items()]
        rows.append(["total", 1000 * total / args.steps, "100.0"])
        print(f"\ntraining step ({args.steps} steps after one warm-up step):")
        print(format_table(["stage", "ms / step", "%"], rows))
        print(
            f"outside forward + backward: {100 * (1 - network / total):.1f} % of the step; "
            f"{args.batch * args.steps / total:.2f} images/s"
        )
    if args.skip_val:
        return
    st, n, metrics = profile_val(
        args.data, args.model, args.weights, args.imgsz, args.batch, args.val_images
    )
    # post-processing: what turns the network output into COCO results (not the scoring)
    post = sum(v for k, v in st.seconds.items() if k not in ("network", "COCOeval (bbox + segm)"))
    rows = [[k, 1000 * v / n] for k, v in st.seconds.items()]
    rows.append(["post-processing (NMS + masks + RLE)", 1000 * post / n])
    rows.append(["post-processing / network", post / st.seconds["network"]])
    print(f"\nvalidation ({n} images, conf {TrainConfig().conf}, max_det {TrainConfig().max_det}):")
    print(format_table(["stage", "ms / image"], rows))
    mask = metrics.get("mask") or {}
    print(
        f"box mAP50-95 {metrics['box']['map50_95']:.6f}  mask mAP50-95 "
        f"{mask.get('map50_95', float('nan')):.6f}"
    )
    dense_s, window_s, n, skipped = compare_postprocess(
        args.data, args.model, args.weights, args.imgsz, args.batch, args.val_images
    )
    print(
        f"\nframe masks as RLEs, same NMS output, alternating per image ({n} images): all "
        f"masks on the full frame + pycocotools {1000 * dense_s / n:.1f} ms/image; windows, "
        f"first {postprocess.COCO_MAX_DETS} per class {1000 * window_s / n:.1f} ms/image "
        f"({dense_s / window_s:.2f}x; {skipped / n:.1f} masks/image not needed by COCO)"
    )


if __name__ == "__main__":
    main()
