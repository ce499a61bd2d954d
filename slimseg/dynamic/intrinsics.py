"""Published pinhole calibrations of the public RGB-D benchmarks, picked by folder name.

Real TUM RGB-D and Bonn folders carry no camera file; the calibration is a property of the
sensor, which the folder name identifies (``rgbd_dataset_freiburg3_walking_xyz`` → freiburg3,
``rgbd_bonn_balloon`` → Bonn). A ``camera.yaml`` in the folder always wins (the synthetic
sequences write one). Depth on all of them: uint16 PNG, 5000 units per metre.

Sources: TUM RGB-D "File Formats / Intrinsic Camera Calibration of the Kinect" page (fr1, fr2,
fr3: the ROS-default-corrected values for the colour camera); the Bonn RGB-D Dynamic dataset
page (fx 542.822841, fy 542.576870, cx 315.593520, cy 237.756098).
"""

from __future__ import annotations

import re
from pathlib import Path

TUM_DEPTH_SCALE = 5000.0  # TUM and Bonn: uint16 depth / 5000 = metres; 0 = invalid

CALIBRATIONS: dict[str, dict[str, float]] = {
    "tum-fr1": {"fx": 517.3, "fy": 516.5, "cx": 318.6, "cy": 255.3},
    "tum-fr2": {"fx": 520.9, "fy": 521.0, "cx": 325.1, "cy": 249.7},
    "tum-fr3": {"fx": 535.4, "fy": 539.2, "cx": 320.1, "cy": 247.6},
    "bonn": {"fx": 542.822841, "fy": 542.576870, "cx": 315.593520, "cy": 237.756098},
}
DEFAULT = "tum-fr1"  # folders whose name says nothing (kept from before the table existed)

_PATTERNS = (
    (re.compile(r"freiburg([123])|(?:^|[_\-])fr([123])(?:[_\-/]|$)"), "tum-fr{}"),
    (re.compile(r"bonn"), "bonn"),
)


def calibration_for(folder: str | Path) -> str | None:
    """Key of :data:`CALIBRATIONS` the folder's name (or its parent's) points at, else None.

    ``rgbd_dataset_freiburg3_walking_xyz`` → ``"tum-fr3"``, ``fr2_desk`` → ``"tum-fr2"``,
    ``rgbd_bonn_crowd`` → ``"bonn"``."""
    p = Path(folder).resolve()
    for name in (p.name, p.parent.name):
        low = name.lower()
        for pattern, key in _PATTERNS:
            m = pattern.search(low)
            if m:
                digits = [g for g in m.groups() if g]
                return key.format(*digits) if digits else key
    return None
