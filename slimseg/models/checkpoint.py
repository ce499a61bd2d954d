"""slimseg weight files: the model spec, class names, mobility priors and (EMA) weights.

A ``.pt`` file written by ``save_weights`` is a plain ``torch.save`` dict (format
``slimseg-weights/1``) of tensors and plain data: it loads without Lightning and with
``torch.load(weights_only=True)``, so nothing is unpickled from a downloaded file.
``load_weights`` also reads Lightning ``.ckpt`` files written by ``slimseg train`` (their EMA
weights when present); those load with ``weights_only=True`` too.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from slimseg.errors import SlimsegError
from slimseg.models.base import ZooModel
from slimseg.models.registry import build_from_spec
from slimseg.models.specs import ModelSpec, spec_from_mapping
from slimseg.utils.atomic import atomic_path
from slimseg.version import __version__

FORMAT = "slimseg-weights/1"


class NotSlimsegWeightsError(SlimsegError):
    """The file holds tensors, but not in a slimseg weights or checkpoint layout."""


@dataclass
class WeightsInfo:
    """What a weights file says about its model besides the tensors."""

    spec: ModelSpec
    names: list[str]
    mobility: list[float]
    epoch: int = -1
    metrics: dict[str, Any] = field(default_factory=dict)
    train_config: dict[str, Any] = field(default_factory=dict)


def save_weights(path: str | Path, model: ZooModel, info: WeightsInfo) -> Path:
    """Write ``model``'s state dict with ``info`` atomically (temp file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "slimseg_version": __version__,
        "spec": info.spec.to_dict(),
        "spec_hash": info.spec.hash,
        "names": list(info.names),
        "mobility": list(info.mobility),
        "epoch": info.epoch,
        "metrics": info.metrics,
        "train_config": info.train_config,
        "fused": model.is_fused,
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def load_weights(path: str | Path, fused: bool = False) -> tuple[nn.Module, WeightsInfo]:
    """Build the model a weights file describes and load its tensors (eval mode).

    ``fused=True`` returns the fused (deploy) model.
    """
    path = Path(path)
    if not path.is_file():
        raise SlimsegError(f"{path}: weights file not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise SlimsegError(
            f"{path}: refusing to unpickle objects from a weights file (only tensors and plain "
            "data load); save its state dict instead: torch.save(model.state_dict(), 'x.pt')"
        ) from None
    except (OSError, RuntimeError, EOFError, ValueError) as exc:
        raise SlimsegError(f"{path}: not a readable checkpoint ({exc})") from None
    if not isinstance(ckpt, dict):
        raise NotSlimsegWeightsError(f"{path}: not a slimseg weights file or Lightning checkpoint")
    if ckpt.get("format") == FORMAT:
        state, meta = ckpt["state_dict"], ckpt
        stored_fused = bool(ckpt.get("fused", False))
    elif "hyper_parameters" in ckpt and "spec" in ckpt["hyper_parameters"]:
        meta = ckpt["hyper_parameters"]
        ema = ckpt.get("ema")
        if ema is not None:
            state = ema["module"]
        else:
            state = {k[6:]: v for k, v in ckpt["state_dict"].items() if k.startswith("model.")}
        meta = {**meta, "epoch": ckpt.get("epoch", -1), "metrics": ckpt.get("metrics", {})}
        stored_fused = False
    else:
        raise NotSlimsegWeightsError(f"{path}: not a slimseg weights file or Lightning checkpoint")
    spec = spec_from_mapping(ModelSpec, meta["spec"], f"{path}:spec")
    model = build_from_spec(spec, fused=stored_fused)
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise SlimsegError(
            f"{path}: weights do not match {spec.name} (missing {list(missing)[:3]}, "
            f"unexpected {list(unexpected)[:3]}); was the file written by another version?"
        )
    model.eval()
    if fused and not stored_fused:
        model = model.fuse()
    info = WeightsInfo(
        spec=spec,
        names=list(meta.get("names", [])),
        mobility=list(meta.get("mobility", [])),
        epoch=int(meta.get("epoch", -1)),
        metrics=dict(meta.get("metrics", {})),
        train_config=dict(meta.get("train", meta.get("train_config", {}))),
    )
    return model, info
