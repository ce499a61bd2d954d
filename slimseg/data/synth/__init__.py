"""Embedded procedural RGB-D dataset: instance segmentation images and TUM-style sequences.

No download: ``generate(out, train, val, imgsz, seed)`` renders everything from a seed
(byte-identical for the same arguments); its report names the written ``data.yaml``. Modules:

- :mod:`.categories`: ``CATEGORIES`` (COCO names, ids, mobility priors);
- :mod:`.painter`, :mod:`.style`, :mod:`.shapes`, :mod:`.person`: per-category shape samplers
  and renderers (:mod:`.person`: the articulated, walking person);
- :mod:`.texture`, :mod:`.camera`: procedural room (wall, floor, clutter) seen by a pinhole;
- :mod:`.scene`: one frame (layered instances, depth, sensor effects), ``render_image``;
- :mod:`.world`, :mod:`.sequence`, :mod:`.presets`: TUM RGB-D sequences (room, objects,
  walkers, camera path; rendered frames with dynamic masks and static backgrounds);
  :mod:`.blur`: their motion blur over a finite exposure;
- :mod:`.coco_writer`, :mod:`.generate`: COCO json, data.yaml (written atomically).
"""

from slimseg.data.synth.categories import CATEGORIES, MOBILITY, NAMES, Category
from slimseg.data.synth.coco_writer import MIN_AREA, encode_mask, frame_annotations
from slimseg.data.synth.generate import SynthReport, generate
from slimseg.data.synth.person import walking_pose
from slimseg.data.synth.scene import (
    DEPTH_SCALE,
    STREAM_TRAIN,
    STREAM_VAL,
    Frame,
    Placement,
    compose,
    frame_rng,
    render_image,
)
from slimseg.data.synth.sequence import (
    SequenceFrame,
    render_sequence_frame,
    timestamp,
    write_sequence,
)
from slimseg.data.synth.shapes import sample_style
from slimseg.data.synth.style import Style
from slimseg.data.synth.world import build_world

__all__ = [
    "CATEGORIES",
    "DEPTH_SCALE",
    "MIN_AREA",
    "MOBILITY",
    "NAMES",
    "STREAM_TRAIN",
    "STREAM_VAL",
    "Category",
    "Frame",
    "Placement",
    "SequenceFrame",
    "Style",
    "SynthReport",
    "build_world",
    "compose",
    "encode_mask",
    "frame_annotations",
    "frame_rng",
    "generate",
    "render_image",
    "render_sequence_frame",
    "sample_style",
    "timestamp",
    "walking_pose",
    "write_sequence",
]
