"""Configs shipped inside the package (``slimseg/configs/<kind>/*.yaml``) and how names resolve.

The YAML files travel with the wheel as package data and are found through
``importlib.resources``, so ``pip install slimseg`` works the same as an editable checkout.

Resolution rule for a value the user passes (``--config``, ``--augment``, ``--classes``,
a spec path): an existing file always wins (a user's own ``configs/`` folder next to their
data keeps working). Otherwise a bare name (``cpu-demo``, ``cpu-demo.yaml``) or the
checkout-relative spelling the docs use (``configs/train/cpu-demo.yaml``) picks the shipped
file of that kind. Anything else is an error that lists the shipped names.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path, PurePath

from slimseg.errors import SlimsegError

KINDS = ("models", "train", "data", "ablation")
_SUFFIXES = (".yaml", ".yml")


def shipped_dir(kind: str) -> Path:
    """Folder of the shipped configs of one kind (``models``, ``train``, ``data``, ``ablation``)."""
    if kind not in KINDS:
        raise ValueError(f"unknown config kind {kind!r}; valid: {', '.join(KINDS)}")
    # A regular (unzipped) install: the traversable is a real folder.
    return Path(str(resources.files("slimseg") / "configs" / kind))


def shipped_names(kind: str) -> list[str]:
    """Stems of the shipped YAML files of one kind, sorted."""
    return sorted(p.stem for p in shipped_dir(kind).iterdir() if p.suffix in _SUFFIXES)


def shipped_file(kind: str, name: str) -> Path:
    """The shipped ``<kind>/<name>.yaml``; a one-line error naming the valid names otherwise."""
    path = shipped_dir(kind) / (name if name.endswith(_SUFFIXES) else f"{name}.yaml")
    if not path.is_file():
        valid = ", ".join(shipped_names(kind))
        raise SlimsegError(f"no shipped {kind} config {name!r}; shipped: {valid}")
    return path


def resolve_config(value: str | Path, kind: str, what: str) -> Path:
    """An existing file, else the shipped config ``value`` names (see the module docstring).

    ``what`` names the kind of file in the error (e.g. ``train config``)."""
    path = Path(value).expanduser()
    if path.is_file():
        return path
    parts = PurePath(str(value)).parts
    bare = len(parts) == 1
    checkout_spelling = len(parts) == 3 and parts[:2] == ("configs", kind)
    if bare or checkout_spelling:
        candidate = shipped_dir(kind) / (
            parts[-1] if parts[-1].endswith(_SUFFIXES) else f"{parts[-1]}.yaml"
        )
        if candidate.is_file():
            return candidate
    valid = ", ".join(shipped_names(kind))
    raise SlimsegError(f"{value}: {what} not found (no such file, nor a shipped one: {valid})")
