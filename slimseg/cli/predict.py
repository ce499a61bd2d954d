"""``slimseg predict``: detections, masks and overlays for images, a folder or a video.

Per frame, in ``--out``: ``<stem>_overlay.png`` (masks tinted, boxes and class labels),
``<stem>_mask.png`` (``uint8``, 255 where any detected object is) and ``<stem>.json``
(``image``, ``size [h, w]``, ``detections`` with ``box`` xyxy frame pixels, ``class``, ``name``,
``score``, ``mobility``, and ``timings_ms``). Semantic models (MSNET) write
``<stem>_classes.png`` (``uint8`` class ids, 0 = background, k + 1 = class k) instead of
detections, a class-colour overlay, the mask of every non-background pixel and a json with
the pixel count per class. Video frames are named ``frame_000000`` onwards.
The files are written into a temporary folder beside ``--out`` that takes its place when the
last frame is done: a run that fails midway leaves ``--out`` as it was. An ``--out`` holding
files slimseg did not write, or one that is (or contains) ``--source``, is refused
(:mod:`slimseg.utils.outputs`); output stems never collide.

With ``--dump-raw DIR`` (an ``.onnx`` model) every frame's network input and raw outputs, as
onnxruntime gave them, also go to ``DIR/<stem>.ssraw`` (:mod:`slimseg.deploy.raw_dump`), with
the frame size, the ORB keypoints ``slimseg dynamic`` would use with their descriptors and
the frame's FAST corners (with ``--dump-depth`` the depth and the camera too: what the C++
chain's multi-frame stages need); the frame itself goes to
``DIR/<stem>.ppm`` and the model's metadata to ``DIR/metadata.json``: the input of the C++
reference consumer's example (``export/cpp``, docs/cpp_consumer.md). ``DIR`` is staged like
``--out``: an interrupted run leaves it as it was.

With ``--track [PRESET]`` (a folder of frames, taken in sorted order, or a video; a single
image is refused) the frames go through the track stage instead and the outputs are
``tracks/<stem>.png`` (``uint16`` instance maps, pixel = track id), ``tracks.csv``,
``tracks.gif`` and ``tracks.mp4``: see :mod:`slimseg.deploy.track_predict`.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from slimseg.cli.arg_types import FRACTION, count, multiple_of, threads
from slimseg.cli.commands import COMMAND_HELP
from slimseg.cli.rerun_args import add_rerun_arg, kept_recording, rerun_path
from slimseg.cli.settings_args import add_settings_args, settings_from_args
from slimseg.data.bags.colour_stream import BagColour
from slimseg.data.bags.reader import is_bag
from slimseg.data.frame_files import IMAGE_SUFFIXES, open_source
from slimseg.data.sample import Sample
from slimseg.data.tum import TumSequence
from slimseg.data.visualize import draw_class_map, draw_sample
from slimseg.deploy.predictor import BACKEND_CHOICES, Predictor, combined_mask
from slimseg.deploy.raw_dump import SUFFIX as RAW_SUFFIX
from slimseg.deploy.raw_dump import frame_dump, write_raw
from slimseg.deploy.track_predict import track_predict
from slimseg.detections import Prediction
from slimseg.dynamic.chain_config import TrackPlan
from slimseg.dynamic.epipolar import orb_features
from slimseg.dynamic.modes import FPS, KEYPOINTS, MAX_KEYPOINTS
from slimseg.errors import SlimsegError
from slimseg.ops.nms_numpy import MAX_DET, NMS_IOU, PREDICT_CONF
from slimseg.utils.atomic import atomic_path, staged_dir, write_json, write_png
from slimseg.utils.outputs import claim_folder, refuse_inputs

STAGES = ("preprocess", "inference", "postprocess")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "predict",
        help=COMMAND_HELP["predict"],
        description="Run an exported .onnx (onnxruntime) or .pt/.ckpt weights (torch) on an "
        "image, a folder of .png/.jpg/.jpeg/.bmp images or a video. Writes per frame "
        "<stem>_overlay.png, <stem>_mask.png (255 = any object) and <stem>.json to --out. "
        "With --track: per-frame track-id maps tracks/<stem>.png, tracks.csv and an annotated "
        "tracks.gif/.mp4 instead, the masks of people just lost included. "
        "Exit 1 if some files could not be read.",
    )
    p.add_argument("--model", required=True, help="model.onnx, weights.pt or checkpoint.ckpt")
    p.add_argument(
        "--source",
        required=True,
        help="an image, a folder of images, a video, or a ROS bag's colour topic (.bag, .mcap, "
        "rosbag2 folder; needs slimseg[ros])",
    )
    p.add_argument("--rgb-topic", help="bag --source: the colour topic (default: the only one)")
    p.add_argument("--conf", type=FRACTION, default=PREDICT_CONF, help="score threshold")
    p.add_argument("--iou", type=FRACTION, default=NMS_IOU, help="NMS IoU threshold")
    p.add_argument(
        "--imgsz",
        type=multiple_of(),
        nargs="+",
        default=None,
        help="network input H [W] (default: the model's; static ONNX graphs only run at theirs)",
    )
    p.add_argument("--backend", default="auto", choices=BACKEND_CHOICES)
    p.add_argument("--threads", type=threads(), default=None, help="intra-op CPU threads")
    p.add_argument("--max-det", type=count(1), default=MAX_DET, help="detections kept per frame")
    p.add_argument("--out", default="runs/predict", help="output folder")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--dump-raw",
        metavar="DIR",
        default=None,
        help="also write each frame's raw network input/outputs (DIR/<stem>.ssraw), the frame "
        "(DIR/<stem>.ppm) and DIR/metadata.json for the C++ consumer (docs/cpp_consumer.md); "
        ".onnx models only",
    )
    p.add_argument(
        "--keypoints",
        type=count(1, MAX_KEYPOINTS),
        default=KEYPOINTS,
        help="--dump-raw: ORB keypoints per frame stored with the outputs (as slimseg dynamic)",
    )
    p.add_argument(
        "--dump-depth",
        metavar="SEQUENCE",
        default=None,
        help="--dump-raw: also each frame's depth (metres), from the TUM-layout sequence whose "
        "rgb/ frames --source names, and its camera: the C++ consumer's depth cut, motion "
        "layers and stillness test then act as slimseg dynamic's",
    )
    add_settings_args(p, masking=False)
    add_rerun_arg(p, "--track's frames: image, class-coloured mask, boxes, keypoints, timing")
    p.set_defaults(run=run)


def save_prediction(
    out_dir: Path,
    stem: str,
    source: str,
    image: np.ndarray,
    pred: Prediction,
    names: list[str],
    frame: int | None = None,
) -> None:
    """Write ``<stem>_overlay.png``, ``<stem>_mask.png`` and ``<stem>.json`` atomically
    (semantic predictions: also ``<stem>_classes.png``)."""
    h, w = pred.image_hw
    if pred.class_map is not None:
        overlay = draw_class_map(image, pred.class_map, names)
        write_png(out_dir / f"{stem}_classes.png", pred.class_map)
        ids, counts = np.unique(pred.class_map, return_counts=True)
        body: dict = {
            "class_pixels": {
                ("background" if i == 0 else names[i - 1]): int(n)
                for i, n in zip(ids.tolist(), counts.tolist(), strict=True)
            }
        }
    else:
        masks = (
            pred.masks.astype(np.uint8)
            if pred.masks is not None
            else np.zeros((len(pred), h, w), np.uint8)
        )
        sample = Sample(image=image, boxes=pred.boxes, classes=pred.classes, masks=masks)
        overlay = draw_sample(sample, names)
        body = {"detections": pred.detections()}
    write_png(out_dir / f"{stem}_overlay.png", overlay)
    write_png(out_dir / f"{stem}_mask.png", combined_mask(pred))
    payload: dict = {"image": source}
    if frame is not None:
        payload["frame"] = frame
    payload |= {"size": [h, w], **body}
    payload["timings_ms"] = {k: round(v, 3) for k, v in pred.timings.items()}
    write_json(out_dir / f"{stem}.json", payload)


def run(args: argparse.Namespace) -> int:
    if not 0 <= args.conf < 1 or not 0 < args.iou <= 1:
        raise SlimsegError(
            f"--conf must be in [0, 1) and --iou in (0, 1], got {args.conf}, {args.iou}"
        )
    if args.max_det < 1:
        raise SlimsegError(f"--max-det must be >= 1, got {args.max_det}")
    _, plan = settings_from_args(args)
    if plan.on:
        if args.dump_raw:
            raise SlimsegError("--dump-raw writes per-frame outputs; drop --track to use it")
        return run_tracked(args, plan)
    if args.rerun is not None:
        raise SlimsegError("--rerun records the track stage's frames: add --track")
    frames, total, is_video = open_source(args.source, args.rgb_topic)
    predictor = Predictor.from_path(
        args.model, backend=args.backend, imgsz=args.imgsz, threads=args.threads
    )
    out_dir = Path(args.out)
    print(f"{predictor} -> {out_dir}")
    dump_dir = None if args.dump_raw is None else Path(args.dump_raw)
    depth_of, camera = _depth_source(args.dump_depth, dump_dir)
    if dump_dir is not None and predictor.backend != "onnxruntime":
        raise SlimsegError(f"--dump-raw needs an exported .onnx model, not {args.model}")
    inputs = _inputs(args)
    sums = dict.fromkeys(STAGES, 0.0)
    done, detections, skipped = 0, 0, []
    start = time.perf_counter()
    bar = tqdm(total=total or None, desc="predict", unit="img", disable=args.quiet)
    # the files (and --dump-raw's folder) appear when every frame is done, never over a
    # folder holding files slimseg did not write
    with (
        bar,
        staged_dir(out_dir, command="predict", inputs=inputs) as stage,
        _dump_stage(dump_dir, inputs | {"--out": out_dir}) as dump_stage,
    ):
        if dump_stage is not None:
            write_json(dump_stage / "metadata.json", predictor.metadata)
        for index, (stem, source, image) in enumerate(frames):
            bar.update(1)
            if image is None:
                skipped.append(source)
                continue
            raw: dict[str, np.ndarray] | None = None if dump_dir is None else {}
            pred = predictor.predict(
                image, conf=args.conf, iou=args.iou, max_det=args.max_det, raw=raw
            )
            if dump_stage is not None and raw is not None:
                depth = None if depth_of is None else depth_of(stem)
                _dump_frame(dump_stage, stem, image, raw, args.keypoints, depth, camera)
            save_prediction(
                stage,
                stem,
                source,
                image,
                pred,
                predictor.names,
                frame=index if is_video else None,
            )
            for k in STAGES:
                sums[k] += pred.timings.get(k, 0.0)
            done += 1
            detections += len(pred)
    elapsed = time.perf_counter() - start
    rate = done / elapsed if elapsed > 0 else 0.0
    stages = ", ".join(f"{k} {sums[k] / max(done, 1):.1f}" for k in STAGES)
    print(
        f"{done} image(s), {detections} detection(s) in {elapsed:.2f} s: {rate:.2f} images/s "
        f"end to end; mean ms per image: {stages}"
    )
    return _report_skipped(skipped)


def _inputs(args: argparse.Namespace) -> dict[str, str | None]:
    """The paths predict reads (an output may neither be nor contain one)."""
    return {"--source": args.source, "--model": args.model, "--dump-depth": args.dump_depth}


@contextmanager
def _dump_stage(dump_dir: Path | None, inputs: dict) -> Iterator[Path | None]:
    """``--dump-raw``'s staged folder (``None`` without it): complete or absent, like --out,
    and neither an input nor ``--out`` (nor inside it)."""
    if dump_dir is None:
        yield None
        return
    refuse_inputs(inputs["--out"], "--out", {"--dump-raw": dump_dir}, folder=True)
    with staged_dir(dump_dir, "--dump-raw", "predict --dump-raw", inputs) as stage:
        yield stage


def _depth_source(
    sequence: str | None, dump_dir: Path | None
) -> tuple[Callable[[str], np.ndarray] | None, tuple[float, float, float, float] | None]:
    """``--dump-depth``: the depth (``float32 [H, W]`` metres) of the frame whose rgb file
    is called ``stem``, from the sequence's associations, and the sequence's camera ``(fx,
    fy, cx, cy)`` px (``(None, None)``: no depth dumped)."""
    if sequence is None:
        return None, None
    if dump_dir is None:
        raise SlimsegError("--dump-depth adds each frame's depth to the raw dumps: add --dump-raw")
    seq = TumSequence(sequence)
    by_stem = {Path(rgb).stem: i for i, ((_, rgb), _) in enumerate(seq.frames)}

    def depth_of(stem: str) -> np.ndarray:
        if stem not in by_stem:
            raise SlimsegError(f"--dump-depth {sequence}: no frame {stem} in its rgb.txt (give "
                               "the sequence whose rgb/ frames --source names)")  # fmt: skip
        return seq.load(by_stem[stem])[1]

    return depth_of, seq.camera.pinhole


def _dump_frame(
    dump_dir: Path,
    stem: str,
    image: np.ndarray,
    raw: dict[str, np.ndarray],
    keypoints: int,
    depth_m: np.ndarray | None = None,
    camera: tuple[float, float, float, float] | None = None,
) -> None:
    """``<stem>.ssraw`` (input, outputs, frame size, the chain's ORB keypoints with their
    descriptors and the FAST corners, the depth and camera if given) and ``<stem>.ppm``."""
    f = orb_features(image, keypoints, corners=True)
    dump = frame_dump(raw, image.shape[:2], f.keypoints, depth_m=depth_m,
                      descriptors=f.descriptors, corners=f.corners, camera=camera)  # fmt: skip
    write_raw(dump_dir / f"{stem}{RAW_SUFFIX}", dump)
    with atomic_path(dump_dir / f"{stem}.ppm") as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
            raise SlimsegError(f"{dump_dir}: cannot write {stem}.ppm")


def run_tracked(args: argparse.Namespace, plan: TrackPlan) -> int:
    """``predict --track``: the frames in order through the track stage."""
    source = Path(args.source)
    if source.is_file() and source.suffix.lower() in IMAGE_SUFFIXES:
        raise SlimsegError(
            f"--track follows objects across frames: give a folder of frames or a video, "
            f"not one image ({source})"
        )
    rerun = rerun_path(args, Path(args.out), _inputs(args))
    if is_bag(source):  # the rate of the header stamps
        bag = BagColour(source, args.rgb_topic)
        frames, total, fps = bag.frames(), len(bag.stamps), bag.fps
    else:
        frames, total, is_video = open_source(source)
        fps = _video_fps(source) if is_video else FPS
    predictor = Predictor.from_path(
        args.model, backend=args.backend, imgsz=args.imgsz, threads=args.threads
    )
    out_dir = Path(args.out)
    claim_folder(out_dir)
    refuse_inputs(out_dir, "--out", _inputs(args), folder=True)
    if not args.quiet:
        print(f"{predictor} -> {out_dir}")
        print(f"track stage: {plan.describe()}")
    viz = None
    if rerun is not None:
        from slimseg.sequence.rerun_frames import RerunFrames

        viz = RerunFrames(rerun, list(predictor.names), "slimseg predict --track")
    with kept_recording(viz):
        report = track_predict(
            predictor, frames, out_dir, plan, args.conf, args.iou, args.max_det, fps=fps,
            total=total, progress=not args.quiet, observers=[] if viz is None else [viz],
        )  # fmt: skip
    print(report.summary())
    for note in report.notes:
        print(note)
    return _report_skipped(report.skipped)


def _video_fps(path: Path) -> float:
    """The video's frame rate (``FPS`` when OpenCV does not know it)."""
    cap = cv2.VideoCapture(str(path))
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS))
    finally:
        cap.release()
    return fps if 0 < fps < 1000 else FPS


def _report_skipped(skipped: list[str]) -> int:
    """Name the unreadable files on stderr; the exit code (1 if any)."""
    if skipped:
        shown = ", ".join(skipped[:5]) + (
            f" (+{len(skipped) - 5} more)" if len(skipped) > 5 else ""
        )
        print(f"skipped {len(skipped)} unreadable file(s): {shown}", file=sys.stderr)
        return 1
    return 0
