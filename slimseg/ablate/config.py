"""Sweep definition: ``configs/ablation/*.yaml`` loaded strictly into frozen dataclasses.

A sweep names its arms (zoo variants, or spec overrides on one: :mod:`slimseg.ablate.arms`),
its data (``synth``: the embedded generated set, or a data YAML), a training recipe plus
overrides, the seeds, the row metrics, the Lightning launch options and the latency bench::

    name: table2-synth
    variants: [yolov8n-seg, yolov8n-seg-gs, {name: m16, model: yolov8n-seg,
                                             spec: {head: {num_masks: 16}}}]
    data: synth                      # or a data.yaml path (relative to this file)
    synth: {train_images: 512, val_images: 128, imgsz: 320, seed: 0}
    train: {recipe: ../train/cpu-demo.yaml, epochs: 10}   # recipe + TrainConfig overrides
    seeds: [0, 1]                    # optional; default: the recipe's seed, one run per arm
    metrics: [coco]                  # optional row metrics (slimseg.ablate.metrics)
    trainer: {accelerator: cpu, devices: "1", num_nodes: 1}
    bench: {imgsz: [320, 640], runs: 20, warmup: 3, threads: 2, masks: true}

The fields added after the first sweeps (``seeds``, ``metrics``, ``bench.imgsz``,
``bench.masks``, ``bench.conf``) and plain-name arms leave the config hash as it was while
they hold their defaults, so sweep folders of older configs still resume.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from slimseg.ablate.arms import Arm, parse_arms
from slimseg.ablate.latency import BenchOptions
from slimseg.ablate.metrics import DEFAULT_METRICS, resolve_metrics
from slimseg.engine.config import TrainConfig, load_train_config
from slimseg.errors import ConfigError, SlimsegError
from slimseg.ops.nms import PREDICT_CONF
from slimseg.utils.outputs import check_folder_name
from slimseg.utils.shipped import resolve_config, shipped_names
from slimseg.utils.strict_dataclass import dataclass_from_mapping
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


# Fields added after the first sweeps, left out of the hash while at these defaults.
_HASH_DEFAULTS: dict[tuple[str, ...], object] = {
    ("seeds",): None,
    ("metrics",): list(DEFAULT_METRICS),
    ("bench", "imgsz"): None,
    ("bench", "masks"): False,
    ("bench", "conf"): PREDICT_CONF,
}


@dataclass(frozen=True)
class AblationConfig:
    """A loaded sweep; ``variants`` are its arms, ``seeds`` None = ``train.seed`` only (and
    the run folders ``variants/NAME/``; with seeds: ``variants/NAME/seed-S/``)."""

    name: str
    variants: tuple[Arm, ...]
    data: str
    train: TrainConfig
    synth: SynthData = field(default_factory=SynthData)
    seeds: tuple[int, ...] | None = None
    metrics: tuple[str, ...] = DEFAULT_METRICS
    trainer: TrainerOptions = field(default_factory=TrainerOptions)
    bench: BenchOptions = field(default_factory=BenchOptions)
    gflops_imgsz: int = 640  # GFLOPs column at the paper's input size
    source: str = ""

    @property
    def run_seeds(self) -> tuple[int, ...]:
        """The seeds every arm trains with."""
        return self.seeds if self.seeds is not None else (self.train.seed,)

    @property
    def bench_sizes(self) -> tuple[int, ...]:
        """Input sizes of the latency bench (default: the training imgsz)."""
        return self.bench.sizes(self.train.imgsz)

    def arm(self, name: str) -> Arm:
        """The arm called ``name``."""
        return next(a for a in self.variants if a.name == name)

    @property
    def data_path(self) -> Path | None:
        """The data YAML, or None for the embedded synthetic set."""
        return None if self.data == SYNTH else Path(self.data)

    def to_dict(self) -> dict:
        """JSON-able dict (stored in the sweep folder; ``source`` excluded)."""
        d = json.loads(json.dumps(dataclasses.asdict(self) | {"variants": []}))
        d["variants"] = [a.to_json() for a in self.variants]
        d.pop("source")
        for keys, default in _HASH_DEFAULTS.items():
            *parents, last = keys
            holder = d
            for key in parents:
                holder = holder[key]
            if holder[last] == default:
                del holder[last]
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
        raise ConfigError(f"{path}: expected a mapping with name, variants, data, train")
    raw = dict(raw)
    train_raw = raw.pop("train", None)
    if not isinstance(train_raw, dict) or "recipe" not in train_raw:
        raise ConfigError(f"{path}: field 'train' needs a mapping with 'recipe' (a train YAML)")
    train_raw = dict(train_raw)
    recipe_value = str(train_raw.pop("recipe"))
    recipe = _relative(path, recipe_value)
    if not recipe.is_file():  # a shipped recipe's name (``cpu-demo``) also works
        try:
            recipe = resolve_config(recipe_value, "train", "train recipe")
        except SlimsegError:
            shipped = ", ".join(shipped_names("train"))
            raise ConfigError(
                f"{path}: train.recipe {recipe} does not exist (shipped recipes: {shipped})"
            ) from None
    base = dataclasses.asdict(load_train_config(recipe))
    train = dataclass_from_mapping(TrainConfig, base | train_raw, f"{path}: train")
    if data is not None:
        raw["data"] = data
    elif isinstance(raw.get("data"), str) and raw["data"] != SYNTH:
        raw["data"] = str(_relative(path, raw["data"]))
    arms = parse_arms(raw.pop("variants", None), path)
    if isinstance(raw.get("bench"), dict) and isinstance(raw["bench"].get("imgsz"), int):
        raw["bench"] = raw["bench"] | {"imgsz": [raw["bench"]["imgsz"]]}  # one size
    cfg = dataclass_from_mapping(AblationConfig, raw | {"train": {}, "variants": []}, str(path))
    cfg = dataclasses.replace(cfg, variants=arms, train=train, source=str(path))
    _check(cfg, path)
    if cfg.data_path is not None and not cfg.data_path.is_file():
        raise ConfigError(
            f"{path}: data {cfg.data_path} does not exist; build it (see "
            "configs/data/coco20-example.yaml) or pass --data DATA.yaml"
        )
    return cfg


def config_from_dict(d: dict, config_hash: str, where: str) -> AblationConfig:
    """The sweep stored in a sweep folder's ``sweep.json`` (``d``: its ``config``, written
    by :meth:`AblationConfig.to_dict`), checked to hash to ``config_hash``; ``where`` names
    the file in errors. What a run on another node trains from: no path of the driver's
    machine (the config file, the recipe) is read again."""
    raw = dict(d)
    train = dataclass_from_mapping(TrainConfig, raw.pop("train", None), f"{where}: train")
    arms = parse_arms(raw.pop("variants", None), Path(where))
    cfg = dataclass_from_mapping(AblationConfig, raw | {"train": {}, "variants": []}, where)
    cfg = dataclasses.replace(cfg, variants=arms, train=train, source=where)
    if cfg.hash != config_hash:
        raise ConfigError(
            f"{where}: the stored config hashes to {cfg.hash}, not {config_hash}: written by "
            "another slimseg version? Run the sweep with the version that started it"
        )
    return cfg


def _check(cfg: AblationConfig, path: Path) -> None:
    """Constraints across fields (the types are checked by ``dataclass_from_mapping``)."""
    check_folder_name(cfg.name, str(path))  # the default --out is runs/ablate/<name>
    if cfg.seeds is not None and (
        not cfg.seeds or len(set(cfg.seeds)) != len(cfg.seeds) or min(cfg.seeds) < 0
    ):
        raise ConfigError(f"{path}: seeds must be a non-empty list of distinct ints >= 0")
    resolve_metrics(cfg.metrics, str(path))
    sizes = cfg.bench.imgsz
    if sizes is not None and (
        not sizes or len(set(sizes)) != len(sizes) or any(s < 32 or s % 32 for s in sizes)
    ):
        raise ConfigError(
            f"{path}: bench.imgsz must be one or more distinct multiples of 32, got {list(sizes)}"
        )
    b = cfg.bench
    if b.runs < 1 or b.warmup < 0 or b.threads < 1 or not 0.0 <= b.conf < 1.0:
        raise ConfigError(
            f"{path}: bench needs runs >= 1, warmup >= 0, threads >= 1 and 0 <= conf < 1"
        )


def _relative(base_file: Path, value: str) -> Path:
    p = Path(value).expanduser()
    return p if p.is_absolute() else (base_file.parent / p).resolve()
