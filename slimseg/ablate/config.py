"""Sweep definition: ``configs/ablation/*.yaml`` loaded strictly into frozen dataclasses.

A sweep names its variants, its data (``synth``: the embedded generated set, or a data YAML),
a training recipe plus overrides, the Lightning launch options and the latency bench::

    name: table2-synth
    variants: [yolov8n-seg, yolov8n-seg-gs, yolov8n-seg-rep, yolov8n-seg-gs-rep]
    data: synth                      # or a data.yaml path (relative to this file)
    synth: {train_images: 512, val_images: 128, imgsz: 320, seed: 0}
    train: {recipe: ../train/cpu-demo.yaml, epochs: 10}   # recipe + TrainConfig overrides
    trainer: {accelerator: cpu, devices: "1", num_nodes: 1}
    bench: {runs: 20, warmup: 3, threads: 2}
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from slimseg.engine.config import TrainConfig, load_train_config
from slimseg.errors import SlimsegError
from slimseg.models.registry import list_models
from slimseg.models.specs import SpecError, spec_from_mapping
from slimseg.utils.shipped import resolve_config, shipped_names
from slimseg.utils.yaml_io import read_yaml

SYNTH = "synth"


@dataclass(frozen=True)
class SynthData:
    """The embedded procedural dataset, generated once into the sweep folder."""

    train_images: int = 512
    val_images: int = 128
    imgsz: int = 320
    seed: int = 0


@dataclass(frozen=True)
class TrainerOptions:
    """Lightning launch: ``devices`` is a count, a list like ``"0,1"`` or ``auto``."""

    accelerator: str = "auto"
    devices: str = "auto"
    num_nodes: int = 1


@dataclass(frozen=True)
class BenchOptions:
    """onnxruntime FP32 latency at the sweep's imgsz: median of ``runs`` after ``warmup``."""

    runs: int = 20
    warmup: int = 3
    threads: int = 2


@dataclass(frozen=True)
class AblationConfig:
    name: str
    variants: tuple[str, ...]
    data: str
    train: TrainConfig
    synth: SynthData = field(default_factory=SynthData)
    trainer: TrainerOptions = field(default_factory=TrainerOptions)
    bench: BenchOptions = field(default_factory=BenchOptions)
    gflops_imgsz: int = 640  # GFLOPs column at the paper's input size
    source: str = ""

    @property
    def data_path(self) -> Path | None:
        """The data YAML, or None for the embedded synthetic set."""
        return None if self.data == SYNTH else Path(self.data)

    def to_dict(self) -> dict:
        """JSON-able dict (stored in the sweep folder; ``source`` excluded)."""
        d = json.loads(json.dumps(dataclasses.asdict(self)))
        d.pop("source")
        return d

    @property
    def hash(self) -> str:
        """12 hex digits identifying what shapes the rows (launch options excluded: a sweep
        started on one GPU may resume on four)."""
        d = self.to_dict()
        d.pop("trainer")
        text = json.dumps(d, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:12]


def load_ablation_config(path: str | Path, data: str | None = None) -> AblationConfig:
    """Read a sweep YAML; ``data`` (a data YAML path) replaces its ``data`` field.

    Relative paths in the file (``data``, ``train.recipe``) resolve against its folder."""
    path = resolve_config(path, "ablation", "ablation config")
    raw = read_yaml(path, "ablation config")
    if not isinstance(raw, dict):
        raise SpecError(f"{path}: expected a mapping with name, variants, data, train")
    raw = dict(raw)
    train_raw = raw.pop("train", None)
    if not isinstance(train_raw, dict) or "recipe" not in train_raw:
        raise SpecError(f"{path}: field 'train' needs a mapping with 'recipe' (a train YAML)")
    train_raw = dict(train_raw)
    recipe_value = str(train_raw.pop("recipe"))
    recipe = _relative(path, recipe_value)
    if not recipe.is_file():  # a shipped recipe's name (``cpu-demo``) also works
        try:
            recipe = resolve_config(recipe_value, "train", "train recipe")
        except SlimsegError:
            shipped = ", ".join(shipped_names("train"))
            raise SpecError(
                f"{path}: train.recipe {recipe} does not exist (shipped recipes: {shipped})"
            ) from None
    base = dataclasses.asdict(load_train_config(recipe))
    train = spec_from_mapping(TrainConfig, base | train_raw, f"{path}: train")
    if data is not None:
        raw["data"] = data
    elif isinstance(raw.get("data"), str) and raw["data"] != SYNTH:
        raw["data"] = str(_relative(path, raw["data"]))
    cfg = spec_from_mapping(AblationConfig, raw | {"train": {}}, str(path))
    cfg = dataclasses.replace(cfg, train=train, source=str(path))
    known = set(list_models())
    unknown = [v for v in cfg.variants if v not in known]
    if unknown:
        raise SpecError(f"{path}: variants {unknown} unknown; valid: {', '.join(sorted(known))}")
    if not cfg.variants or len(set(cfg.variants)) != len(cfg.variants):
        raise SpecError(f"{path}: variants must be a non-empty list without repeats")
    if cfg.data_path is not None and not cfg.data_path.is_file():
        raise SpecError(
            f"{path}: data {cfg.data_path} does not exist; build it (see "
            "configs/data/coco20-example.yaml) or pass --data DATA.yaml"
        )
    return cfg


def _relative(base_file: Path, value: str) -> Path:
    p = Path(value).expanduser()
    return p if p.is_absolute() else (base_file.parent / p).resolve()
