"""Sweep arms: a zoo variant by name, or a named spec override on a zoo variant's spec.

``variants:`` in a sweep config lists arms, each either a zoo name (``slimseg info`` lists
them) or a mapping::

    variants:
      - yolov8n-seg                               # plain: the shipped spec as it is
      - name: yolov8n-seg-m16                     # the arm's name: its folder and row label
        model: yolov8n-seg                        # the zoo spec it starts from (default: name)
        spec: {head: {num_masks: 16}}             # deep-merged onto that spec's fields

The override is merged key by key into nested mappings (a list or a scalar replaces the
base value whole), then checked as strictly as a spec file: an unknown field, a wrong type
or an invalid value is a one-line error naming the config file and the arm. The merged
spec is named after the arm, so its checkpoints and exports say which arm they are.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from slimseg.errors import SlimsegError
from slimseg.models.registry import get_spec, list_models
from slimseg.models.specs import ModelSpec, SpecError, spec_from_mapping
from slimseg.utils.outputs import check_folder_name

ARM_FIELDS = ("name", "model", "spec")


@dataclass(frozen=True)
class Arm:
    """One sweep arm: ``name`` (unique in the sweep), base zoo ``model``, ``spec`` override
    (a nested mapping of ModelSpec fields; empty for a plain zoo variant)."""

    name: str
    model: str
    spec: Mapping[str, Any] = field(default_factory=dict)

    @property
    def plain(self) -> bool:
        """True for a zoo variant used as shipped (its row may have a paper counterpart)."""
        return self.name == self.model and not self.spec

    def to_json(self) -> str | dict[str, Any]:
        """A plain arm is its name (so configs written before arms keep their hash)."""
        if self.plain:
            return self.name
        return {"name": self.name, "model": self.model, "spec": json.loads(json.dumps(self.spec))}

    def model_spec(self, where: str = "") -> ModelSpec:
        """The arm's spec: the zoo spec of ``model`` with ``spec`` deep-merged onto it.

        ``where`` prefixes error messages (the config file)."""
        base = get_spec(self.model)
        if self.plain:
            return base
        merged = deep_merge(base.to_dict(), self.spec) | {"name": self.name}
        return spec_from_mapping(ModelSpec, merged, f"{where}arm {self.name}: spec")


def deep_merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``override`` merged in: mappings recursively, anything else replaced."""
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def parse_arms(raw: Any, path: Path) -> tuple[Arm, ...]:
    """``variants:`` of the sweep file ``path`` → arms, each checked (its spec built once)."""
    if not isinstance(raw, list) or not raw:
        raise SpecError(f"{path}: variants must be a non-empty list of zoo names or arms")
    known = set(list_models())
    arms = tuple(_parse_arm(item, i, path, known) for i, item in enumerate(raw))
    names = [a.name for a in arms]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise SpecError(f"{path}: variants {repeated} repeat; every arm needs its own name")
    for arm in arms:
        arm.model_spec(f"{path}: ")  # a bad override fails at load, not after hours
    return arms


def _parse_arm(item: Any, i: int, path: Path, known: set[str]) -> Arm:
    if isinstance(item, str):
        if item not in known:
            raise SpecError(
                f"{path}: variants ['{item}'] unknown; valid: {', '.join(sorted(known))}"
            )
        return Arm(item, item)
    where = f"{path}: variants[{i}]"
    if not isinstance(item, dict):
        raise SpecError(f"{where}: expected a zoo name or a mapping with {list(ARM_FIELDS)}")
    unknown = sorted(set(item) - set(ARM_FIELDS))
    if unknown:
        raise SpecError(f"{where}: unknown field(s) {unknown}; valid fields: {list(ARM_FIELDS)}")
    name = item.get("name")
    try:
        check_folder_name(name, str(where))
    except SlimsegError as exc:
        raise SpecError(str(exc)) from None
    model = item.get("model", name)
    if model not in known:
        raise SpecError(
            f"{where} ({name}): model {model!r} unknown; valid: {', '.join(sorted(known))}"
        )
    spec = item.get("spec") or {}
    if name in known and (model != name or spec):
        raise SpecError(
            f"{where}: arm name {name!r} is a zoo variant; give the override its own name"
        )
    if not isinstance(spec, dict):
        raise SpecError(f"{where} ({name}): 'spec' must be a mapping of model spec fields")
    if "name" in spec:
        raise SpecError(f"{where} ({name}): drop spec.name; the arm's 'name' names its spec")
    return Arm(name, str(model), spec)
