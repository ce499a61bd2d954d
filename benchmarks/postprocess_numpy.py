"""The runtime's post-processing side by side: numpy (what every predictor runs since the core
install needs no torch) vs the torch path it replaced (``outputs_to_frame_detections``: NMS
with torchvision, mask assembly with torch), on one model's outputs for a sequence's frames.

Both run on the same network outputs (one onnxruntime call per frame, done first), one
thread each (``torch.set_num_threads(1)``, as ``Masker.from_onnx(threads=1)``), alternating
frame by frame so a load change hits both alike. Prints milliseconds per frame (median and
mean) of each at each score threshold, the torch/numpy ratio, and the mask pixels that differ
(float32 rounding at the 0.5 threshold, ``tests/deploy/test_postprocess_numpy.py``).

    python benchmarks/postprocess_numpy.py --model runs/demo/export/yolov8n-seg-gs-rep.onnx \\
        --sequence runs/demo/slam/sequence --conf 0.25 0.05
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from slimseg.data.tum import TumSequence
from slimseg.deploy.predict_postprocess import instance_predictions
from slimseg.deploy.predictor import Predictor
from slimseg.eval.postprocess import outputs_to_frame_detections
from slimseg.ops.nms_numpy import MAX_DET, NMS_IOU


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", required=True, help="an exported instance-segmentation .onnx")
    ap.add_argument("--sequence", required=True, nargs="+", help="TUM-layout sequence folders")
    ap.add_argument("--conf", type=float, nargs="+", default=[0.25, 0.05])
    ap.add_argument("--frames", type=int, default=40, help="frames per sequence")
    args = ap.parse_args()
    torch.set_num_threads(1)
    p = Predictor.from_path(args.model, threads=1)
    outputs = []
    for folder in args.sequence:
        seq = TumSequence(folder)
        for i in range(min(args.frames, len(seq))):
            x, meta = p.preprocess(seq.load(i)[0])
            pred, proto = p.runner(x)
            outputs.append((pred, proto, meta))
    print(f"{p}: {len(outputs)} frames, one thread")
    print("conf    dets/frame  torch ms (median, mean)  numpy ms (median, mean)  torch/numpy  "
          "mask pixels differing")  # fmt: skip
    for conf in args.conf:
        t_torch, t_numpy, dets, differ = [], [], 0, 0
        for pred, proto, meta in outputs:
            t0 = time.perf_counter()
            (ref,) = outputs_to_frame_detections(
                torch.from_numpy(pred), torch.from_numpy(proto), [meta], p.family,
                p.num_classes, conf, NMS_IOU, MAX_DET,
            )  # fmt: skip
            t1 = time.perf_counter()
            (got,) = instance_predictions(
                pred, proto, [meta], p.names, p.mobility, p.family, conf, NMS_IOU, MAX_DET
            )
            t2 = time.perf_counter()
            t_torch.append(1000 * (t1 - t0))
            t_numpy.append(1000 * (t2 - t1))
            dets += len(ref)
            same = len(ref) == len(got) and (ref.boxes == got.boxes).all()
            differ += int((ref.masks != got.masks).sum()) if same else -1
        mt, mn = np.median(t_torch), np.median(t_numpy)
        print(
            f"{conf:<7} {dets / len(outputs):>10.1f}  {mt:>8.2f}, {np.mean(t_torch):>6.2f}"
            f"{'':>10}{mn:>8.2f}, {np.mean(t_numpy):>6.2f}{'':>10}{mt / mn:>6.2f}x  "
            f"{differ if differ >= 0 else 'detections differ'}"
        )


if __name__ == "__main__":
    main()
