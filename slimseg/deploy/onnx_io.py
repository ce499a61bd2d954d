"""Writing an export: nothing reaches its final path half-written or unchecked.

Every exporter (FP32/FP16 :mod:`slimseg.deploy.onnx_export`, INT8
:mod:`slimseg.deploy.int8_export`) works in a :func:`staging_dir` beside the output, writes the
finished graph there with :func:`stage` (metadata stamped, ONNX checker passed), runs its own
gate on that file, and only then calls :func:`publish`: the ``NAME.json`` sidecar is written
in the staging folder and both files are renamed into place (same filesystem, so each rename
is atomic). A gate that raises leaves nothing at the output path.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
from pathlib import Path
from typing import Any

import onnx

from slimseg.deploy.metadata import to_metadata_props
from slimseg.errors import SlimsegError
from slimseg.utils.outputs import claim_file, json_with

log = logging.getLogger(__name__)


def check_onnx_name(out: Path) -> None:
    """``SlimsegError`` unless ``out`` names a ``.onnx`` file (``.``, ``..`` or ``''`` do not:
    its sidecar would have no name, or be itself)."""
    if out.suffix.lower() != ".onnx" or out.name in ("", ".", ".."):
        raise SlimsegError(f"--out {out}: give a file name ending in .onnx")


def sidecar_path(out: Path) -> Path:
    """The metadata sidecar of an export: ``NAME.onnx`` → ``NAME.json`` (``out`` passed
    :func:`check_onnx_name`)."""
    check_onnx_name(out)
    return out.with_suffix(".json")


def owned_export(out: Path) -> bool:
    """``out`` (a ``.onnx`` path) and its sidecar are an earlier slimseg export: both exist
    and the sidecar is slimseg's metadata (it records ``slimseg_version``)."""
    out = out.with_suffix(".onnx")
    return out.is_file() and json_with(sidecar_path(out), dict, "slimseg_version")


def claim_export(out: Path) -> None:
    """``SlimsegError`` when ``out`` or its sidecar is an existing folder, when ``out`` does
    not end in ``.onnx`` (its sidecar would be itself), or when either is an existing file
    slimseg did not write (:func:`owned_export`): an export replaces an earlier export only,
    never a user's ``annotations.json`` that happens to share the stem."""
    check_onnx_name(out)
    for path in (out, sidecar_path(out)):
        if path.is_dir():
            raise SlimsegError(
                f"--out {out}: {path} is a folder; give the file to write, e.g. "
                f"{out / 'model.onnx'}"
            )
    claim_file(out, "--out", owned_export, "ONNX graph")
    claim_file(sidecar_path(out), "--out", lambda p: owned_export(out), "metadata sidecar")


def staging_dir(out: Path) -> tempfile.TemporaryDirectory:
    """A temporary folder beside ``out`` (created with its parents), removed on exit with
    whatever is left in it. Use as ``with staging_dir(out) as tmp:``; :func:`claim_export`'s
    refusals come first, before any export work."""
    claim_export(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    return tempfile.TemporaryDirectory(dir=out.parent, prefix=f".{out.stem}.")


def stamp_metadata(proto: onnx.ModelProto, meta: dict[str, Any]) -> None:
    """Replace ``proto``'s ``metadata_props`` with ``meta`` (every value a JSON string)."""
    del proto.metadata_props[:]
    for key, value in to_metadata_props(meta).items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value


def stage(proto: onnx.ModelProto, meta: dict[str, Any], tmp_dir: str | Path, name: str) -> Path:
    """Stamp ``meta`` into ``proto``, run the ONNX checker and save it as ``tmp_dir/name``;
    returns that path (the candidate a gate then runs)."""
    stamp_metadata(proto, meta)
    onnx.checker.check_model(proto)
    candidate = Path(tmp_dir) / name
    onnx.save(proto, str(candidate))
    return candidate


def publish(candidate: Path, meta: dict[str, Any], out: Path) -> Path:
    """Write the sidecar beside the staged ``candidate``, then rename the graph to ``out`` and
    the sidecar to :func:`sidecar_path` of ``out``; returns the sidecar's path."""
    sidecar_tmp = candidate.parent / "sidecar.json"
    sidecar_tmp.write_text(json.dumps(meta, indent=1))
    os.replace(candidate, out)
    sidecar = sidecar_path(out)
    os.replace(sidecar_tmp, sidecar)
    log.debug("wrote %s and %s", out, sidecar)
    return sidecar
