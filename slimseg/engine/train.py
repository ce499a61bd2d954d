"""``slimseg train`` as a library call: data config + variant + recipe → a trained run folder.

Run folder layout::

    OUT/weights/last.pt, best.pt   EMA weights + spec + names + mobility (slimseg-weights/1)
    OUT/checkpoints/last.ckpt      Lightning state for --resume
    OUT/tb/                        TensorBoard logs
    OUT/results.csv                one row per validation: epoch, losses, mAPs (mIoU, MPA)
    OUT/args.yaml                  model, data, recipe of the run
"""

from __future__ import annotations

import csv
import dataclasses
import logging
import os
import shutil
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import lightning as L
import torch
import yaml
from lightning.pytorch.callbacks import ModelCheckpoint, TQDMProgressBar
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.plugins.io import TorchCheckpointIO

from slimseg.data.augment import AugmentConfig
from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.engine.banners import quiet_device_banners
from slimseg.engine.config import TrainConfig
from slimseg.engine.freeze import FreezeModules, frozen_children
from slimseg.engine.module import ZooModule
from slimseg.engine.precision import resolve_precision
from slimseg.errors import SlimsegError
from slimseg.losses.instance_mask import target_mask_ratio
from slimseg.models.checkpoint import (
    NotSlimsegWeightsError,
    WeightsInfo,
    load_weights,
    save_weights,
)
from slimseg.models.pretrained import load_pretrained
from slimseg.models.registry import get_spec
from slimseg.models.specs import ModelSpec
from slimseg.utils.atomic import atomic_path
from slimseg.utils.threads import torch_threads

logger = logging.getLogger(__name__)

# Lightning notices that are noise for slimseg runs (short CPU epochs, pytree deprecation).
QUIET_WARNINGS = (
    r".*is smaller than the logging interval.*",
    r".*isinstance\(treespec, LeafSpec\)` is deprecated.*",
    r".*does not have many workers which may be a bottleneck.*",
)


class RunWriter(L.Callback):
    """After each validation (rank 0): ``weights/best.pt`` (highest mask mAP50-95, box for
    detection-only models, mIoU for semantic models), then ``last.pt``, and a ``results.csv``
    row."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.best = -1.0

    def on_validation_end(self, trainer: L.Trainer, module: ZooModule) -> None:
        if not trainer.is_global_zero or trainer.sanity_checking:
            return
        metrics = trainer.callback_metrics
        epoch = min(trainer.current_epoch, module.cfg.epochs - 1)  # validate() after fit: +1
        keys = ("val/miou", "val/mask_map50_95", "val/box_map50_95")
        key = next((k for k in keys if k in metrics), keys[-1])
        score = float(metrics.get(key, 0.0))
        info = WeightsInfo(
            spec=module.spec,
            names=module.names,
            mobility=module.mobility,
            epoch=epoch,
            metrics=module.last_metrics,
            train_config=dataclasses.asdict(module.cfg),
        )
        # best.pt first: last.pt holding the recipe's last epoch is what tells a resumed sweep
        # the run is trained (ablate.sweep.trained_epochs); a run killed between the two
        # writes must not look finished without its best.pt
        if score > self.best:  # best = highest mIoU / mask mAP50-95 / box mAP50-95
            self.best = score
            save_weights(self.out / "weights" / "best.pt", module.eval_model, info)
        save_weights(self.out / "weights" / "last.pt", module.eval_model, info)
        row = {"epoch": epoch}
        row |= {k: round(float(v), 6) for k, v in metrics.items() if "/" in k}
        path = self.out / "results.csv"
        new = not path.exists()
        if not new:  # keep the header's columns (a validate-only row has no train terms)
            with path.open(newline="") as f:
                row = dict.fromkeys(next(csv.reader(f)), "") | row
        with path.open("a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(row), extrasaction="ignore")
            if new:
                writer.writeheader()
            writer.writerow(row)

    def state_dict(self) -> dict:
        return {"best": self.best}

    def load_state_dict(self, state: dict) -> None:
        self.best = float(state.get("best", -1.0))


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning checkpoints written to a temp file in the same folder, then renamed: a run
    killed while saving never leaves a truncated ``last.ckpt``."""

    def save_checkpoint(
        self, checkpoint: dict, path: str | Path, storage_options: object = None
    ) -> None:
        with atomic_path(path) as tmp:
            torch.save(checkpoint, tmp)


def check_resume_checkpoint(path: Path, module: L.LightningModule) -> None:
    """``SlimsegError`` naming ``path`` unless it loads as a Lightning checkpoint (tensors and
    plain types only, ``weights_only``) holding ``module``'s tensors with their shapes: a
    truncated file, another file type or another model's run fails here, not inside Lightning
    after the run folder was written to."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # a truncated zip, a pickle it refuses, not a torch file at all
        reason = str(e).strip().splitlines()[0][:120] if str(e).strip() else type(e).__name__
        raise SlimsegError(
            f"{path}: cannot be read as a training checkpoint ({reason}); restore a copy, or "
            "start a new run without --resume"
        ) from None
    state = ckpt.get("state_dict") if isinstance(ckpt, dict) else None
    if not isinstance(state, dict) or "epoch" not in ckpt:
        raise SlimsegError(f"{path}: not a slimseg training checkpoint (no state_dict / epoch)")
    own = module.state_dict()
    bad = [k for k, v in own.items() if k not in state or tuple(state[k].shape) != v.shape]
    if bad:
        raise SlimsegError(
            f"{path}: holds another model ({len(bad)} of {len(own)} tensors missing or of "
            f"another shape, e.g. {bad[0]}); resume with the --model and --data of that run"
        )


def next_run_dir(base: Path) -> Path:
    """``base`` if free (or empty), else ``base-2``, ``base-3``, ..."""
    if not base.exists() or not any(base.iterdir()):
        return base
    k = 2
    while (candidate := base.with_name(f"{base.name}-{k}")).exists():
        k += 1
    return candidate


RUN_DIR_ENV = "SLIMSEG_RUN_DIR"


@contextmanager
def unfinished_run_removed(out: Path, own: bool, existed: bool) -> Iterator[None]:
    """On any exception (a corrupt image, Ctrl-C: Lightning's ``SystemExit``) before the
    first checkpoint, remove what this run wrote in ``out`` (the folder too when ``existed``
    is False), so no run folder stays without a checkpoint; a run with ``last.ckpt`` is kept
    for ``--resume``. ``own``: the folder is this run's (not a resumed one, not a DDP child)."""
    try:
        yield
    except BaseException:
        if own and not (out / "checkpoints" / "last.ckpt").is_file() and out.is_dir():
            if existed:  # the user's empty folder: emptied again
                for entry in out.iterdir():
                    _remove(entry)
            else:
                shutil.rmtree(out, ignore_errors=True)
            logger.info("removed the unfinished run folder %s (no checkpoint yet)", out)
        raise


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _is_launcher_process() -> bool:
    """True in the process a user started (not a DDP child re-launched by Lightning)."""
    return os.environ.get("LOCAL_RANK", "0") == "0" and os.environ.get("NODE_RANK", "0") == "0"


def resolve_run_dir(out: Path, resume: bool) -> Path:
    """The run folder: ``out`` when resuming, else a fresh ``out[-k]``; DDP child ranks reuse
    the folder the launching rank chose (passed down in ``SLIMSEG_RUN_DIR``)."""
    inherited = os.environ.get(RUN_DIR_ENV)
    if inherited and not _is_launcher_process():
        return Path(inherited)
    chosen = out if resume else next_run_dir(out)
    chosen.mkdir(parents=True, exist_ok=True)
    return chosen


def transfer_weights(module: ZooModule, path: str | Path) -> str:
    """Initialise from ``path``: slimseg weights/checkpoints (tensors with matching names and
    shapes) or a reference YOLOv8 state dict (mapped by structure, COCO class rows picked by
    name). Returns a report of what loaded and what was skipped."""
    try:
        source, _ = load_weights(path)
    except NotSlimsegWeightsError:
        report = load_pretrained(path, module.model, module.names).format()
    else:
        own = module.model.state_dict()
        matched = {
            k: v for k, v in source.state_dict().items() if k in own and own[k].shape == v.shape
        }
        if not matched:
            raise SlimsegError(f"{path}: no tensor matches {module.spec.name}; wrong --weights?")
        module.model.load_state_dict(matched, strict=False)
        skipped = sorted(set(own) - set(matched))
        report = f"loaded {len(matched)} of {len(own)} tensors from {path}"
        if skipped:
            report += f"; kept the initial values of {len(skipped)} (e.g. {', '.join(skipped[:3])})"
    if module.ema is not None:
        module.ema.module.load_state_dict(module.model.state_dict())
    return report


def train(
    model: str | ModelSpec,
    data: str | Path,
    cfg: TrainConfig,
    out: Path,
    resume: bool = False,
    devices: int | str = "auto",
    num_nodes: int = 1,
    accelerator: str = "auto",
    weights: str | None = None,
    augment: AugmentConfig | None = None,
    progress: bool = True,
    callbacks: list[L.Callback] | None = None,
    precision: str = "auto",
    freeze: Sequence[str] = (),
) -> tuple[ZooModule, Path]:
    """Train ``model`` on ``data`` with recipe ``cfg``; returns the module and run folder.

    ``model``: a zoo name, a spec YAML path, or a :class:`ModelSpec` (its class count is
    replaced by the data's, as for the other two).

    ``callbacks`` are added to the run's own (checkpointing, run writer, progress bar).
    ``cfg.threads`` (when set) is torch's thread count during the call only. ``precision``:
    one of :data:`~slimseg.engine.precision.PRECISIONS` (``auto`` follows ``cfg.amp``).
    ``freeze``: top-level parts of the network kept fixed (``engine/freeze.py``), e.g.
    ``("backbone", "neck", "detect")`` to train only the mask branch on a trained trunk."""
    with torch_threads(cfg.threads):
        return _train(
            model,
            data,
            cfg,
            out,
            resume,
            devices,
            num_nodes,
            accelerator,
            weights,
            augment,
            progress,
            callbacks,
            precision,
            tuple(freeze),
        )


def _train(
    model: str | ModelSpec,
    data: str | Path,
    cfg: TrainConfig,
    out: Path,
    resume: bool,
    devices: int | str,
    num_nodes: int,
    accelerator: str,
    weights: str | None,
    augment: AugmentConfig | None,
    progress: bool,
    callbacks: list[L.Callback] | None,
    precision: str,
    freeze: tuple[str, ...],
) -> tuple[ZooModule, Path]:
    data_cfg = load_data_config(data)
    if isinstance(model, ModelSpec):
        spec = model.with_classes(len(data_cfg.names))
    else:
        spec = get_spec(model, len(data_cfg.names))
    use_gpu = accelerator in ("gpu", "cuda") or (
        accelerator == "auto" and torch.cuda.is_available()
    )
    lightning_precision = resolve_precision(precision, cfg.amp, use_gpu)  # before any write
    last_ckpt = out / "checkpoints" / "last.ckpt"
    if resume and not last_ckpt.is_file():
        raise SlimsegError(f"{last_ckpt}: nothing to resume (no checkpoint in {out})")
    L.seed_everything(cfg.seed, workers=True, verbose=False)
    module = ZooModule(
        spec.to_dict(), dataclasses.asdict(cfg), list(data_cfg.names), list(data_cfg.mobility)
    )
    if freeze:
        frozen_children(module.model, freeze)  # a bad name fails before anything is written
        callbacks = [*(callbacks or []), FreezeModules(freeze)]
    if resume:
        check_resume_checkpoint(last_ckpt, module)  # before the run folder is touched
    fresh = not resume and _is_launcher_process()
    existed = (out if resume else next_run_dir(out)).exists()
    out = resolve_run_dir(out, resume)
    with unfinished_run_removed(out, fresh, existed):
        if weights and not resume:
            logger.info(transfer_weights(module, weights))
        dm = SegDataModule(
            data_cfg,
            cfg.imgsz,
            cfg.batch,
            cfg.workers,
            augment or AugmentConfig(),
            cfg.seed,
            mask_ratio=target_mask_ratio(spec),
            semantic=module.semantic,
            mosaic_epochs=cfg.epochs - cfg.close_mosaic,
        )
        if _is_launcher_process():
            os.environ[RUN_DIR_ENV] = str(out)  # DDP child ranks inherit the folder chosen here
            (out / "args.yaml").write_text(
                yaml.safe_dump(
                    {
                        "model": spec.name if isinstance(model, ModelSpec) else model,
                        "data": str(data),
                        "spec": spec.to_dict(),
                        "train": dataclasses.asdict(cfg),
                        **({"freeze": list(freeze)} if freeze else {}),
                    },
                    sort_keys=False,
                )
            )
        multi = num_nodes > 1 or (devices not in ("auto", 1, "1"))
        with quiet_device_banners():  # never before a data error's one line
            trainer = L.Trainer(
                max_epochs=cfg.epochs,
                accelerator=accelerator,
                devices=devices,
                num_nodes=num_nodes,
                strategy="ddp" if multi else "auto",
                precision=lightning_precision,
                gradient_clip_val=cfg.grad_clip or None,
                sync_batchnorm=cfg.sync_bn and multi,
                logger=TensorBoardLogger(str(out), name="", version="tb", default_hp_metric=False),
                callbacks=[
                    # checkpoints/last.ckpt every epoch: a killed run loses one epoch at most
                    ModelCheckpoint(
                        dirpath=out / "checkpoints",
                        filename="last",
                        save_top_k=1,
                        every_n_epochs=1,
                        save_on_train_epoch_end=True,  # Lightning's default waits for validation
                        enable_version_counter=False,
                    ),
                    RunWriter(out),
                    *(callbacks or []),
                    *([TQDMProgressBar(refresh_rate=1)] if progress else []),
                ],
                check_val_every_n_epoch=cfg.val_every,
                num_sanity_val_steps=0,
                log_every_n_steps=5,
                enable_progress_bar=progress,
                enable_model_summary=False,
                default_root_dir=str(out),
                plugins=[AtomicCheckpointIO()],
            )
        with warnings.catch_warnings():
            for message in QUIET_WARNINGS:
                warnings.filterwarnings("ignore", message=message)
            trainer.fit(module, datamodule=dm, ckpt_path=str(last_ckpt) if resume else None)
            if module.validated_epoch != cfg.epochs - 1 and not trainer.interrupted:
                # epochs is not a multiple of val_every: score the final weights anyway
                trainer.validate(module, datamodule=dm, verbose=False)
    return module, out
