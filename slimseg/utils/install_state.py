"""What this slimseg install holds: the distributions the core and each extra need, read from
the one place that lists them (``pyproject.toml`` beside the package in a source checkout, else
the installed package's metadata, which is built from it), and which of them are installed.
``slimseg info`` prints it; nothing here imports an extra's modules."""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

CORE = ""  # the key of the core install's requirements
#: what each user-facing extra enables (pyproject.toml ``[project.optional-dependencies]``;
#: ``dev`` is the test suite's and not listed)
EXTRA_USES = {
    "train": "train, val, export, bench, ablate, demo, data synth/show/check, .pt/.ckpt "
    "weights, info's model table",
    "ros": "ROS 1 / ROS 2 bags and MCAP as --sequence / --source, bag2tum, tum2bag, "
    "--bag-out (docs/bags.md)",
    "slam": "slam-eval and slam (ORB-SLAM3, evo; GPL-3.0), the demo's SLAM stage",
    "viz": "--rerun FILE.rrd recordings (dynamic, predict --track, slam-eval)",
    "ray": "ablate --backend ray",
    "openvino": "--backend openvino (predict, dynamic, val, bench; Predictor, slimseg.Masker)",
    "calibrate": "calibrate (a model's own masking settings; Optuna), the demo's calibration",
}
_NAME = re.compile(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)")
_EXTRA = re.compile(r"""extra\s*==\s*['"]([^'"]+)['"]""")


@dataclass(frozen=True)
class ExtraState:
    """One extra (or the core, name ``""``): its distributions, installed ones with versions."""

    name: str
    first: str
    versions: dict[str, str]
    missing: list[str]

    @property
    def installed(self) -> bool:
        return not self.missing

    def describe(self) -> str:
        """``installed``; ``not installed`` when its first distribution (the one it is for:
        torch, rosbags, ...) is missing; else ``missing a, b``."""
        if not self.missing:
            return "installed"
        if self.missing[0] == self.first:
            return "not installed"
        return f"missing {', '.join(self.missing)}"


def requirements() -> dict[str, list[str]]:
    """Distribution names per extra, :data:`CORE` for the core install."""
    tree = Path(__file__).resolve().parents[2] / "pyproject.toml"  # beside slimseg/
    project = {}
    if tree.is_file():
        project = tomllib.loads(tree.read_text(encoding="utf-8")).get("project", {})
    if project.get("name") == "slimseg":  # a source checkout: its own list, not an old install's
        out = {CORE: [_name(r) for r in project["dependencies"]]}
        for extra, reqs in project.get("optional-dependencies", {}).items():
            out[extra] = [_name(r) for r in reqs]
        return out
    out = {CORE: []}
    for req in metadata.requires("slimseg") or []:
        m = _EXTRA.search(req)
        out.setdefault(m.group(1) if m else CORE, []).append(_name(req))
    return out


def _name(requirement: str) -> str:
    m = _NAME.match(requirement)
    if m is None:
        raise ValueError(f"not a requirement: {requirement!r}")
    return m.group(1)


def install_state() -> list[ExtraState]:
    """The core, then each extra of :data:`EXTRA_USES`, with what of them is installed."""
    reqs = requirements()
    states = []
    for name in (CORE, *EXTRA_USES):
        versions, missing = {}, []
        for dist in reqs.get(name, []):
            try:
                versions[dist] = metadata.version(dist)
            except metadata.PackageNotFoundError:
                missing.append(dist)
        first = reqs[name][0] if reqs.get(name) else ""
        states.append(ExtraState(name, first, versions, missing))
    return states
