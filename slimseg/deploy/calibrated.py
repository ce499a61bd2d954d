"""A model's own masking settings: the ``calibrated`` preset ``slimseg calibrate`` writes into an
export's metadata, and how every consumer finds it.

The export's ``slam_masking`` entry holds the recommended settings flat (what the C++ consumer
and :class:`slimseg.Masker` read by default) and every named preset. A calibrated export names
``calibrated`` as its preset, holds its values flat, keeps the shipped presets beside it under
``presets``, and records under ``calibration`` what the settings were chosen on, the
objective, and the digest of the report (:func:`with_calibration`). A model without one falls
back to the shipped defaults, and the consumer says so once (:func:`model_masking`).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from slimseg.deploy.metadata import masking_from_metadata, read_onnx_metadata, slam_masking_entry
from slimseg.dynamic.familiarity import Expectation
from slimseg.dynamic.masking_settings import (
    CALIBRATED,
    DEFAULT,
    DEFAULT_PRESET,
    MaskingSettings,
)
from slimseg.errors import SlimsegError

log = logging.getLogger(__name__)


def is_calibrated(meta: dict[str, Any]) -> bool:
    """Does the export's metadata carry a ``calibrated`` preset?"""
    entry = meta.get("slam_masking")
    presets = entry.get("presets") if isinstance(entry, dict) else None
    return isinstance(presets, dict) and CALIBRATED in presets


def calibration_info(meta: dict[str, Any]) -> dict[str, Any] | None:
    """What the ``calibrated`` preset was chosen on (None: not calibrated)."""
    entry = meta.get("slam_masking")
    info = entry.get("calibration") if isinstance(entry, dict) else None
    return info if isinstance(info, dict) and is_calibrated(meta) else None


def uncalibrated_note(model: str | Path) -> str:
    """The one line a consumer says about a model without a ``calibrated`` preset."""
    return (
        f"{model}: no calibrated masking preset in its metadata; using the shipped "
        f"defaults ({DEFAULT_PRESET}); slimseg calibrate --model {model} --out "
        "CALIBRATED.onnx chooses its own"
    )


def model_masking(meta: dict[str, Any], model: str | Path) -> tuple[MaskingSettings, str | None]:
    """The settings a consumer uses by default for the export ``model``: its ``calibrated``
    preset, else the shipped defaults; and the note to say once (None: calibrated)."""
    if is_calibrated(meta):
        return masking_from_metadata(meta, CALIBRATED), None
    return DEFAULT, uncalibrated_note(model)


def is_own(meta: dict[str, Any], settings: MaskingSettings) -> bool:
    """Are ``settings`` the export's own calibrated preset?"""
    return is_calibrated(meta) and settings == masking_from_metadata(meta, CALIBRATED)


def expectation(meta: dict[str, Any], settings: MaskingSettings) -> Expectation | None:
    """What the export's calibration measured, for the chain to compare its masks with
    (:mod:`slimseg.dynamic.familiarity`): only when ``settings`` are its calibrated ones (a
    user's own choice is not second-guessed) and the export records the measurement."""
    info = calibration_info(meta)
    expect = info.get("expect") if info else None
    if not isinstance(expect, dict) or not is_own(meta, settings):
        return None
    share, static = expect.get("mask_share"), expect.get("static_share")
    if not all(isinstance(v, int | float) and 0 <= v <= 1 for v in (share, static)):
        raise SlimsegError(f"export metadata slam_masking.calibration.expect: expected two "
                           f"shares in [0, 1], got {str(expect)[:80]}")  # fmt: skip
    return Expectation(float(share), float(static), DEFAULT)


def read_model_metadata(path: str | Path) -> dict[str, Any]:
    """The slimseg metadata of the ONNX file ``path`` (read through onnxruntime, the core
    install's engine); a one-line :class:`SlimsegError` when it cannot be read."""
    import onnxruntime as ort

    try:
        opts = ort.SessionOptions()
        opts.log_severity_level = 3
        session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own exception types
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise SlimsegError(f"{path}: not a readable ONNX model ({first})") from None
    return read_onnx_metadata(path, dict(session.get_modelmeta().custom_metadata_map))


def with_calibration(
    meta: dict[str, Any], settings: MaskingSettings, provenance: dict[str, Any]
) -> dict[str, Any]:
    """``meta`` with ``settings`` as its ``calibrated`` preset and recommended settings; the
    shipped presets (this version's) beside it; ``provenance`` under ``calibration``."""
    entry = slam_masking_entry()
    entry.update(settings.as_dict())
    entry["preset"] = CALIBRATED
    entry["presets"][CALIBRATED] = settings.as_dict()
    entry["calibration"] = dict(provenance)
    return {**meta, "slam_masking": entry}


def check_calibrated_out(model: Path, out: Path) -> None:
    """One-line :class:`SlimsegError` unless ``out`` may take the calibrated copy of
    ``model``: a new ``.onnx`` name, or an earlier slimseg export; never ``model`` itself."""
    from slimseg.deploy.onnx_io import claim_export

    if out.resolve() == model.resolve():
        raise SlimsegError(f"--out {out} is the --model itself: give a new file name")
    claim_export(out)


def write_calibrated(
    model: Path, out: Path, settings: MaskingSettings, provenance: dict[str, Any]
) -> Path:
    """Copy the export ``model`` to ``out`` with the ``calibrated`` preset in its metadata
    (ONNX ``metadata_props`` and the ``out``'s ``.json`` sidecar), staged then renamed; never
    over ``model`` itself or a file that is not an earlier slimseg export. Returns ``out``."""
    import onnx

    from slimseg.deploy.onnx_io import publish, stage, staging_dir

    check_calibrated_out(model, out)
    proto = onnx.load(str(model))
    props = {p.key: p.value for p in proto.metadata_props}
    meta = with_calibration(read_onnx_metadata(model, props), settings, provenance)
    with staging_dir(out) as tmp:
        candidate = stage(proto, meta, tmp, out.name)
        publish(candidate, meta, out)
    log.info("wrote %s with its calibrated preset", out)
    return out
