"""Post-processing + masking per frame: the C++ reference consumer vs the Python path.

    python benchmarks/cpp_postprocess.py --model export/m.onnx --source frames/ [--mode fusion]
    python benchmarks/cpp_postprocess.py --model export/m.onnx          # synthetic 640x480 frames

Dumps every frame's raw onnxruntime outputs once (``slimseg predict --dump-raw``'s format), then
times, on those same dumps and in the same run, (a) the Python path ``slimseg dynamic`` uses:
``instance_predictions`` / ``semantic_predictions`` (NMS, boxes and masks on the frame) +
``objects_of`` + ``process_frame`` (dilation, Eq. 1/3/4), torch on one thread; and (b) the
C++ library through its example ``slimseg_masks`` (built here with CMake, -O2, one thread),
whose own clock covers ``Postprocessor::run`` + ``dynamic_mask`` per frame (file reading
excluded on both sides). Prints ms per frame of each, alternating ``--repeats`` times, and the
ratio. The network itself is not timed. Scores at the masking threshold (``slam_masking.conf``).
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from slimseg.data.images import read_rgb
from slimseg.deploy.metadata import masking_from_metadata
from slimseg.deploy.predict_postprocess import instance_predictions, semantic_predictions
from slimseg.deploy.predictor import Predictor
from slimseg.deploy.raw_dump import frame_dump, read_raw, write_raw
from slimseg.dynamic.epipolar import orb_features
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.pipeline import FrameRules, process_frame
from slimseg.dynamic.semantic import objects_of
from slimseg.ops.letterbox import letterbox_params
from slimseg.ops.nms import MAX_DET, NMS_IOU
from slimseg.utils.atomic import write_json
from slimseg.utils.threads import torch_threads

ROOT = Path(__file__).resolve().parents[1]


def build_example(build: Path) -> Path:
    """``slimseg_masks`` built from export/cpp into ``build`` (Release, -O2)."""
    subprocess.run(
        ["cmake", "-S", str(ROOT / "export" / "cpp"), "-B", str(build),
         "-DCMAKE_BUILD_TYPE=Release", "-DCMAKE_CXX_FLAGS_RELEASE=-O2",
         "-DCMAKE_UNITY_BUILD=ON", "-DSLIMSEG_TESTS=OFF"],
        check=True, capture_output=True,
    )  # fmt: skip
    subprocess.run(["cmake", "--build", str(build), "-j", "2"], check=True, capture_output=True)
    return build / "slimseg_masks"


def frames_of(source: Path | None, count: int) -> list[np.ndarray]:
    """RGB frames of ``source`` (sorted .png/.jpg), or ``count`` synthetic 640x480 scenes."""
    if source is not None:
        paths = sorted(p for p in source.iterdir() if p.suffix.lower() in (".png", ".jpg"))
        return [read_rgb(p) for p in paths[:count]]
    rng = np.random.default_rng(0)
    out = []
    for _ in range(count):
        yy, xx = np.mgrid[:480, :640].astype(np.float32)
        img = np.stack([xx / 640, yy / 480, np.full_like(xx, 0.5)], -1)
        for _ in range(8):
            cx, cy, r = rng.uniform(0, 640), rng.uniform(0, 480), rng.uniform(20, 160)
            img[(xx - cx) ** 2 + (yy - cy) ** 2 < r**2] = rng.random(3, dtype=np.float32)
        out.append((img * 255).astype(np.uint8))
    return out


def python_ms(
    predictor: Predictor, dumps: list[dict], mode: str, conf: float, counts: list[int]
) -> float:
    """Mean ms per frame of the Python post-processing + masking on the dumps (appends each
    frame's object count to ``counts``)."""
    masking = masking_from_metadata(predictor.metadata)
    rules = FrameRules(np.asarray(predictor.mobility, np.float32), mode, masking)
    total = 0.0
    with torch_threads(1):
        for d in dumps:
            h, w = (int(v) for v in d["frame_hw"])
            meta = {"letterbox": letterbox_params(h, w, *predictor.imgsz), "orig_shape": (h, w)}
            t0 = time.perf_counter()
            if predictor.task == "semantic":
                logits = torch.from_numpy(d["logits"].astype(np.float32))
                (pred,) = semantic_predictions(logits, [meta], predictor.names)
            else:
                out0 = torch.from_numpy(d["output0"].astype(np.float32))
                out1 = d.get("output1")
                proto = None if out1 is None else torch.from_numpy(out1.astype(np.float32))
                (pred,) = instance_predictions(
                    out0, proto, [meta], predictor.names, predictor.mobility,
                    predictor.family, conf, NMS_IOU, MAX_DET,
                )  # fmt: skip
            objects = objects_of(pred, (h, w))
            counts.append(len(objects))
            inputs = FrameInputs(d["keypoints"], objects)
            process_frame(inputs=inputs, settings=rules)
            total += time.perf_counter() - t0
    return 1000 * total / len(dumps)


def cpp_ms(example: Path, dump_dir: Path, out: Path, mode: str, conf: float) -> float:
    cmd = [str(example), "--meta", str(dump_dir / "metadata.json"), "--dumps", str(dump_dir)]
    cmd += ["--out", str(out), "--mode", mode, "--conf", str(conf)]
    text = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return float(re.search(r"masking ([0-9.]+) ms per frame", text).group(1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, required=True, help="exported .onnx")
    ap.add_argument("--source", type=Path, default=None, help="folder of frames")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--mode", default="fusion", choices=("seg", "box", "fusion"))
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    predictor = Predictor.from_path(args.model, threads=1)
    conf = masking_from_metadata(predictor.metadata).conf
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        example = build_example(root / "build")
        dump_dir = root / "dumps"
        write_json(dump_dir / "metadata.json", predictor.metadata)
        for i, image in enumerate(frames_of(args.source, args.frames)):
            raw: dict[str, np.ndarray] = {}
            predictor.predict(image, conf=1.0, raw=raw)
            kps = orb_features(image, 1000).keypoints
            write_raw(dump_dir / f"{i:06d}.ssraw", frame_dump(raw, image.shape[:2], kps))
        dumps = [read_raw(p) for p in sorted(dump_dir.glob("*.ssraw"))]
        py, cc, counts = [], [], []
        for _ in range(args.repeats):  # alternating, so load changes hit both
            py.append(python_ms(predictor, dumps, args.mode, conf, counts))
            cc.append(cpp_ms(example, dump_dir, root / "out", args.mode, conf))
    h, w = dumps[0]["frame_hw"]
    p, c = statistics.median(py), statistics.median(cc)
    print(f"{predictor}, {len(dumps)} frames of {h}x{w}, mode {args.mode}, score > {conf}, "
          f"{statistics.mean(counts):.1f} objects per frame")  # fmt: skip
    print(f"post-processing + masking per frame (median of {args.repeats}): Python {p:.2f} ms, "
          f"C++ {c:.2f} ms; Python / C++ = {p / c:.1f}x")  # fmt: skip


if __name__ == "__main__":
    main()
