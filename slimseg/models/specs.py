"""Model specs: frozen dataclasses read from ``slimseg/configs/models/*.yaml``, checked strictly."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from slimseg.errors import ConfigError, SlimsegError
from slimseg.utils.strict_dataclass import dataclass_from_mapping
from slimseg.utils.yaml_io import read_yaml

FAMILIES = ("yolov8", "darknet-yolov3", "msnet")
TASKS = ("segment", "detect", "semantic")
HEAD_KINDS = ("decoupled", "shared-rep", "yolov3")
NECKS = ("c2f", "slim")


MAX_SCALE = 2.0  # compound depth/width multipliers (YOLOv8x: 1.0 / 1.25)
MAX_CHANNELS = 4096  # any channel count of a spec (reference sizes reach 1024)
MAX_CLASSES = 65535


class SpecError(ConfigError):
    """A model spec is malformed; the message names the file and field."""


@dataclass(frozen=True)
class ScaleSpec:
    """YOLOv8 compound scale: repeats ×depth, channels ×width capped at max_channels.

    Maps the reference (scale-1.0) channel counts and repeats to this scale
    (``docs/architecture.md`` §2)."""

    depth: float
    width: float
    max_channels: int = 1024

    def __post_init__(self) -> None:
        # checked before anything is allocated: width 64 would ask for 64x the channels
        for name, value, hi in (("depth", self.depth, MAX_SCALE), ("width", self.width, MAX_SCALE)):
            if not (math.isfinite(value) and 0 < value <= hi):
                raise SpecError(f"scale.{name}={value} must be in (0, {hi:g}]")
        if not 8 <= self.max_channels <= MAX_CHANNELS:
            raise SpecError(f"scale.max_channels={self.max_channels} must be in 8..{MAX_CHANNELS}")

    def channels(self, c: int) -> int:
        """``ceil_to_8(min(c, max_channels) · width)``."""
        return int(math.ceil(min(c, self.max_channels) * self.width / 8) * 8)

    def repeats(self, n: int) -> int:
        """``max(round(n · depth), 1)``."""
        return max(round(n * self.depth), 1)


MASK_LOSS_RESOLUTIONS = ("proto", "input")
PROTO_STRIDES = (4, 2)
PROTO_SKIP_STRIDES = (2, 4)  # backbone features the prototype path can take
# fields added after specs were first hashed: left out of ``to_dict`` at their defaults, so
# older specs, their hashes and checkpoints stay exactly what they were
_OMIT_AT_DEFAULT = {"omit_at_default": True}


@dataclass(frozen=True)
class MaskLossSpec:
    """How the instance-mask term is supervised (``docs/architecture.md`` §7).

    ``resolution``: ``proto`` compares ``coeffs · protos`` with the ground truth shrunk to the
    prototype grid (the reference); ``input`` upsamples the predicted logits (bilinear, half
    pixel centres) to the input resolution inside each box and compares them with the
    full-resolution ground truth. ``dice``: weight of a soft-Dice term added to the BCE
    (per instance, over its box). ``thin``: extra BCE weight on thin parts, the ground-truth
    pixels a 5 × 5 opening removes (limbs narrower than 5 px at the target resolution).
    """

    resolution: str = "proto"
    dice: float = 0.0
    thin: float = 0.0

    def __post_init__(self) -> None:
        if self.resolution not in MASK_LOSS_RESOLUTIONS:
            raise SpecError(
                f"mask_loss.resolution={self.resolution!r} is not one of "
                f"{list(MASK_LOSS_RESOLUTIONS)}"
            )
        if self.dice < 0 or self.thin < 0:
            raise SpecError(f"mask_loss.dice and .thin must be >= 0, got {self.dice}, {self.thin}")


@dataclass(frozen=True)
class HeadSpec:
    """Detection head. ``hidden`` and ``proto_channels`` are reference (width 1.0) channels.

    ``proto_stride``: prototypes at 1/4 (the reference) or 1/2 of the input; ``proto_skips``:
    backbone strides (2: the stem conv, 4: the stride-4 C2f) fed into the prototype path
    through 1 × 1 laterals. ``mask_loss``: see :class:`MaskLossSpec`.
    """

    kind: str = "decoupled"
    reg_max: int = 16
    num_masks: int = 32
    proto_channels: int = 256
    hidden: int = 256
    share_repconv: bool = True
    proto_stride: int = field(default=4, metadata=_OMIT_AT_DEFAULT)
    proto_skips: tuple[int, ...] = field(default=(), metadata=_OMIT_AT_DEFAULT)
    mask_loss: MaskLossSpec = field(default_factory=MaskLossSpec, metadata=_OMIT_AT_DEFAULT)

    def __post_init__(self) -> None:
        sizes = (("reg_max", self.reg_max, 64), ("num_masks", self.num_masks, 256),
                 ("proto_channels", self.proto_channels, MAX_CHANNELS),
                 ("hidden", self.hidden, MAX_CHANNELS))  # fmt: skip
        for name, value, hi in sizes:
            if not 1 <= value <= hi:
                raise SpecError(f"head.{name}={value} must be in 1..{hi}")
        if self.proto_stride not in PROTO_STRIDES:
            raise SpecError(
                f"head.proto_stride={self.proto_stride} is not one of {list(PROTO_STRIDES)}"
            )
        skips = self.proto_skips
        if len(set(skips)) != len(skips) or not set(skips) <= set(PROTO_SKIP_STRIDES):
            raise SpecError(
                f"head.proto_skips={list(skips)}: distinct values from {list(PROTO_SKIP_STRIDES)}"
            )
        if any(s < self.proto_stride for s in skips):
            raise SpecError(
                f"head.proto_skips={list(skips)}: a skip finer than proto_stride "
                f"{self.proto_stride} would be thrown away; drop it or set proto_stride: 2"
            )


@dataclass(frozen=True)
class MSNetSpec:
    """MSNET (VTD-SLAM) sizes; see :mod:`slimseg.models.msnet.model` for the design.

    Per pyramid level C2..C5 (strides 4, 8, 16, 32): ``channels`` of the convolutional map,
    ``embed_dims``/``depths``/``heads`` of its PEncoder (transformer width, blocks, heads).
    Tokens are patches of ``max(1, token_stride / level stride)`` pixels of the level's map;
    position embeddings are learned for a ``pos_imgsz`` square input and interpolated to
    other sizes. ``hidden``: width of the head (class queries, pixel features);
    ``decoder_layers``/``decoder_heads``: its Transformer decoder.
    """

    stem_channels: int
    channels: tuple[int, ...]
    embed_dims: tuple[int, ...]
    depths: tuple[int, ...]
    heads: tuple[int, ...]
    hidden: int
    decoder_layers: int
    decoder_heads: int
    mlp_ratio: float = 2.0
    token_stride: int = 32
    pos_imgsz: int = 640
    dropout: float = 0.0

    def __post_init__(self) -> None:
        for name in ("channels", "embed_dims", "depths", "heads"):
            values = getattr(self, name)
            if len(values) != 4 or min(values) < 1 or max(values) > MAX_CHANNELS:
                raise SpecError(
                    f"msnet.{name}: need 4 values in 1..{MAX_CHANNELS} (C2..C5), got {values}"
                )
        for dim, heads in zip(self.embed_dims, self.heads, strict=True):
            if dim % heads:
                raise SpecError(f"msnet.embed_dims {dim} is not divisible by heads {heads}")
        if self.hidden % self.decoder_heads:
            raise SpecError(
                f"msnet.hidden {self.hidden} is not divisible by decoder_heads {self.decoder_heads}"
            )
        if self.token_stride not in (4, 8, 16, 32):
            raise SpecError(f"msnet.token_stride must be 4, 8, 16 or 32, got {self.token_stride}")
        if self.pos_imgsz % 32 or self.pos_imgsz < 32:
            raise SpecError(f"msnet.pos_imgsz must be a multiple of 32, got {self.pos_imgsz}")
        if not 0.0 <= self.dropout < 1.0:
            raise SpecError(f"msnet.dropout must be in [0, 1), got {self.dropout}")


@dataclass(frozen=True)
class ModelSpec:
    """Everything needed to build a network; stored with its hash in checkpoints and exports."""

    name: str
    family: str
    task: str
    num_classes: int = 80
    scale: ScaleSpec | None = None
    neck: str = "c2f"
    head: HeadSpec = field(default_factory=HeadSpec)
    anchors: tuple[tuple[tuple[int, int], ...], ...] | None = None
    description: str = ""
    msnet: MSNetSpec | None = None  # family "msnet" only

    def __post_init__(self) -> None:
        checks = (
            ("family", self.family, FAMILIES),
            ("task", self.task, TASKS),
            ("head.kind", self.head.kind, HEAD_KINDS),
            ("neck", self.neck, NECKS),
        )
        for name, value, valid in checks:
            if value not in valid:
                raise SpecError(f"{self.name}: {name}={value!r} is not one of {list(valid)}")
        if not 1 <= self.num_classes <= MAX_CLASSES:
            raise SpecError(
                f"{self.name}: num_classes must be >= 1 and <= {MAX_CLASSES}, "
                f"got {self.num_classes}"
            )
        if self.family == "yolov8" and self.scale is None:
            raise SpecError(f"{self.name}: yolov8 specs need a 'scale' section")
        if (self.family == "msnet") != (self.msnet is not None):
            raise SpecError(
                f"{self.name}: an 'msnet' section is required for family msnet and only there"
            )
        if (self.family == "msnet") != (self.task == "semantic"):
            raise SpecError(f"{self.name}: task 'semantic' goes with family 'msnet' (and only it)")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (tuples become lists).

        ``msnet`` is left out when unset, so specs (and hashes, checkpoints) of the other
        families are exactly what they were before the field existed.
        """
        data = _compact(self)
        if data.get("msnet") is None:
            data.pop("msnet", None)
        return data

    @property
    def hash(self) -> str:
        """First 12 hex digits of the SHA-256 of the canonical JSON of the spec."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:12]

    def with_classes(self, num_classes: int | None) -> ModelSpec:
        """Copy with another class count (None keeps the spec's)."""
        if num_classes is None or num_classes == self.num_classes:
            return self
        return dataclasses.replace(self, num_classes=num_classes)


def _compact(obj: Any) -> Any:
    """``dataclasses.asdict`` as plain JSON types, without the fields marked
    ``omit_at_default`` that hold their default value."""
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if f.metadata.get("omit_at_default"):
                default = (
                    f.default_factory()
                    if f.default_factory is not dataclasses.MISSING
                    else f.default
                )
                if value == default:
                    continue
            out[f.name] = _compact(value)
        return out
    return json.loads(json.dumps(obj)) if isinstance(obj, (tuple, list)) else obj


def spec_from_mapping(cls: type, data: Any, where: str) -> Any:
    """Build the spec dataclass ``cls`` from a mapping; malformed fields raise SpecError."""
    return dataclass_from_mapping(cls, data, where, SpecError)


def load_spec(path: str | Path) -> ModelSpec:
    """Read one model spec YAML file."""
    try:
        data = read_yaml(path, "model spec")
    except SlimsegError as exc:
        raise SpecError(str(exc)) from None
    return spec_from_mapping(ModelSpec, data, str(path))
