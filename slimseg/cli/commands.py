"""The commands ``slimseg`` knows, without importing them: name, module and one-line help.

``slimseg --help`` lists them from this table, and ``slimseg <command>`` imports only that
command's module (its ``add_parser(subparsers)`` and ``run(args) -> int``), so neither pays
for another command's dependencies (torch for ``train``, onnxruntime for ``dynamic``). Each
command module takes its ``help=`` from :data:`COMMAND_HELP`, so the text has one home.
"""

from __future__ import annotations

from typing import NamedTuple


class Command(NamedTuple):
    name: str
    module: str
    help: str


COMMANDS = (
    Command(
        "demo",
        "slimseg.cli.demo",
        "end to end on the embedded dataset: synth → train (CPU) → val → plots → "
        "ONNX → ORB-SLAM3 with and without the masks",
    ),
    Command(
        "info",
        "slimseg.cli.info",
        "model size and cost (params, gradients, GFLOPs ours and paper convention)",
    ),
    Command(
        "data",
        "slimseg.cli.data",
        "datasets: synth, coco-subset, voc2coco, check, show, bag2tum, tum2bag",
    ),
    Command(
        "train",
        "slimseg.cli.train",
        "train a model (Lightning: CPU, GPU, multi-GPU / multi-node DDP)",
    ),
    Command(
        "val",
        "slimseg.cli.val",
        "COCO box/mask mAP (or mIoU/MPA) of weights or an exported ONNX on a val split",
    ),
    Command(
        "ablate",
        "slimseg.cli.ablate",
        "train and compare variants or spec overrides under one recipe and its "
        "seeds (the paper's Table II)",
    ),
    Command(
        "export",
        "slimseg.cli.export",
        "fused ONNX (FP32/FP16/INT8) with metadata and a verified parity or accuracy check",
    ),
    Command(
        "predict",
        "slimseg.cli.predict",
        "masks, boxes and overlays for images, a folder or a video",
    ),
    Command(
        "bench",
        "slimseg.cli.bench",
        "latency: torch unfused/fused vs onnxruntime FP32/FP16 (/INT8), with ratios",
    ),
    Command(
        "dynamic",
        "slimseg.cli.dynamic",
        "dynamic-keypoint masks for a TUM RGB-D sequence (+ precision/recall with GT)",
    ),
    Command(
        "calibrate",
        "slimseg.cli.calibrate",
        "choose a model's own masking settings on sequences it never saw (its 'calibrated' "
        "preset, written into a copy of the export)",
    ),
    Command(
        "slam-eval",
        "slimseg.cli.slam_eval",
        "trajectory error (ATE/RPE, evo) of ORB-SLAM3 on raw vs masked RGB-D frames",
    ),
    Command(
        "slam",
        "slimseg.cli.slam",
        "SLAM helpers: vocab (DBoW2 ORB vocabulary for ORB-SLAM3)",
    ),
)

COMMAND_HELP = {c.name: c.help for c in COMMANDS}
