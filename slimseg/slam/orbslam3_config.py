"""ORB-SLAM3 RGB-D settings file (OpenCV-YAML, ``File.version "1.0"``) from a sequence's camera.

ORB-SLAM3 reads the calibration, the depth scale and the ORB extractor parameters from this
file. slimseg hands it depth in metres (``RGBD.DepthMapFactor: 1.0``), colour in RGB order
(``Camera.RGB: 1``), and no distortion (TUM's own ORB-SLAM settings also leave the RGB-D
images undistorted). The extractor values are ORB-SLAM3's published TUM RGB-D ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from slimseg.data.frame_source import Camera
from slimseg.dynamic.degrade import FAST_THRESHOLD, PYRAMID_LEVELS, PYRAMID_SCALE
from slimseg.dynamic.modes import FPS, KEYPOINTS
from slimseg.utils.atomic import write_text

# Kinect-class sensor: virtual stereo baseline (m) and the close/far point limit in baselines
BASELINE_M = 0.08
TH_DEPTH = 40.0


@dataclass(frozen=True)
class OrbSlam3Config:
    """ORB extractor and sensor parameters written next to the intrinsics."""

    features: int = KEYPOINTS
    # the degrading rule's static support counts the corners of this pyramid at this threshold
    scale_factor: float = PYRAMID_SCALE
    levels: int = PYRAMID_LEVELS
    ini_fast: int = FAST_THRESHOLD
    min_fast: int = 7
    fps: float = FPS


def settings_text(camera: Camera, width: int, height: int, orb: OrbSlam3Config) -> str:
    """The settings file's text for a ``width``×``height`` pinhole ``camera`` (px)."""
    values: list[tuple[str, object]] = [
        ("File.version", '"1.0"'),
        ("Camera.type", '"PinHole"'),
        ("Camera1.fx", camera.fx),
        ("Camera1.fy", camera.fy),
        ("Camera1.cx", camera.cx),
        ("Camera1.cy", camera.cy),
        ("Camera1.k1", 0.0),
        ("Camera1.k2", 0.0),
        ("Camera1.p1", 0.0),
        ("Camera1.p2", 0.0),
        ("Camera.width", int(width)),
        ("Camera.height", int(height)),
        ("Camera.fps", round(orb.fps)),
        ("Camera.RGB", 1),
        ("Stereo.ThDepth", TH_DEPTH),
        ("Stereo.b", BASELINE_M),
        ("RGBD.DepthMapFactor", 1.0),
        ("ORBextractor.nFeatures", int(orb.features)),
        ("ORBextractor.scaleFactor", float(orb.scale_factor)),
        ("ORBextractor.nLevels", int(orb.levels)),
        ("ORBextractor.iniThFAST", int(orb.ini_fast)),
        ("ORBextractor.minThFAST", int(orb.min_fast)),
        ("Viewer.KeyFrameSize", 0.05),
        ("Viewer.KeyFrameLineWidth", 1.0),
        ("Viewer.GraphLineWidth", 0.9),
        ("Viewer.PointSize", 2.0),
        ("Viewer.CameraSize", 0.08),
        ("Viewer.CameraLineWidth", 3.0),
        ("Viewer.ViewpointX", 0.0),
        ("Viewer.ViewpointY", -0.7),
        ("Viewer.ViewpointZ", -1.8),
        ("Viewer.ViewpointF", 500.0),
    ]
    lines = ["%YAML:1.0", ""]
    for key, v in values:
        lines.append(f"{key}: {_fmt(v)}")
    return "\n".join(lines) + "\n"


def write_settings(
    path: Path, camera: Camera, width: int, height: int, orb: OrbSlam3Config | None = None
) -> Path:
    """Write the settings file (atomically) and return its path."""
    return write_text(path, settings_text(camera, width, height, orb or OrbSlam3Config()))


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return repr(float(v)) if "." in repr(float(v)) else f"{v:.1f}"
    return str(v)
