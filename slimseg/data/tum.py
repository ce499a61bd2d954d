"""TUM RGB-D format: sequence reader (lists, RGB↔depth association, frames in metres), ground
truth and trajectory files (read and written), and the benchmarks' published intrinsics.

Layout (TUM RGB-D, Bonn, and ``slimseg data synth --sequences``)::

    rgb.txt  depth.txt        "timestamp filename" per line, '#' lines are comments
    rgb/<t>.png               8-bit colour (read and returned as RGB)
    depth/<t>.png             16-bit depth, metres = value / depth_scale (5000 on TUM); 0 = invalid
    groundtruth.txt           "timestamp tx ty tz qx qy qz qw" (optional)
    camera.yaml               optional intrinsics: fx, fy, cx, cy, depth_scale

Association follows TUM's ``associate.py``: greedy by smallest |t_rgb - t_depth|, each stamp used
at most once, pairs further apart than ``max_dt`` (0.02 s) dropped.

``camera.yaml`` is read strictly: a key must be one slimseg reads (:data:`CAMERA_KEYS`) or
one it knows to ignore (:data:`CAMERA_EXTRA_KEYS`, ORB-SLAM's dotted settings), every value a
finite number > 0; keys it lacks come from the folder-name calibration below. Depth must be
uint16, and the first frame's median depth must be plausible
(:data:`~slimseg.data.frame_source.DEPTH_RANGE_M`) at the
depth scale in use.

Intrinsics: Published pinhole calibrations of the public RGB-D benchmarks, picked by folder name.

Real TUM RGB-D and Bonn folders carry no camera file; the calibration is a property of the
sensor, which the folder name identifies (``rgbd_dataset_freiburg3_walking_xyz`` → freiburg3,
``rgbd_bonn_balloon`` → Bonn). A ``camera.yaml`` in the folder always wins (the synthetic
sequences write one). Depth on all of them: uint16 PNG, 5000 units per metre.

Sources: TUM RGB-D "File Formats / Intrinsic Camera Calibration of the Kinect" page (fr1, fr2,
fr3: the ROS-default-corrected values for the colour camera); the Bonn RGB-D Dynamic dataset
page (fx 542.822841, fy 542.576870, cx 315.593520, cy 237.756098).
"""

from __future__ import annotations

import difflib
import logging
import re
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.frame_source import (
    DEPTH_RANGE_M,
    Associations,
    Camera,
    Frame,
    PairedFrames,
    Stamped,
    implausible_median_depth,
)
from slimseg.data.images import decode_file
from slimseg.data.value_checks import FrameChecks, check_intrinsics, check_pose
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_text
from slimseg.utils.input_files import read_capped
from slimseg.utils.outputs import inside_root
from slimseg.utils.text import printable
from slimseg.utils.yaml_io import MAX_YAML_BYTES, load_yaml_text

log = logging.getLogger(__name__)

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


# TUM freiburg1: the fallback for a folder whose name and files say nothing (see intrinsics)
TUM_FR1 = {**CALIBRATIONS["tum-fr1"], "depth_scale": TUM_DEPTH_SCALE}
MAX_DT = 0.02  # s, associate.py's default max_difference


MAX_LIST_BYTES = 1 << 30  # rgb.txt / depth.txt / groundtruth.txt: ~40 bytes a line


def _read_lines(path: Path) -> list[tuple[int, str]]:
    """Non-empty, non-comment lines of a text file with their 1-based numbers."""
    try:
        text = read_capped(path, "list", MAX_LIST_BYTES).decode("utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise SlimsegError(f"cannot read {path}: {e}") from None
    out = []
    for no, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if line and not line.startswith("#"):
            out.append((no, line))
    return out


def read_list(path: str | Path) -> list[Stamped]:
    """Parse a TUM ``rgb.txt`` / ``depth.txt``: ``[(timestamp s, relative file path), ...]``
    in file order. Raises ``SlimsegError`` naming the file and line for a malformed line."""
    path = Path(path)
    out: list[Stamped] = []
    for no, line in _read_lines(path):
        parts = line.split()
        try:
            if len(parts) != 2:
                raise ValueError
            t = float(parts[0])
            if not np.isfinite(t):
                raise ValueError
        except ValueError:
            raise SlimsegError(
                f"{path}:{no}: expected 'timestamp filename', got {line!r}"
            ) from None
        inside_root(path.parent, parts[1], f"{path}:{no}")  # never a file outside the sequence
        out.append((t, parts[1]))
    return out


def associate(rgb: list[Stamped], depth: list[Stamped], max_dt: float = MAX_DT) -> Associations:
    """Pair RGB and depth entries greedily by smallest ``|t_rgb - t_depth|`` (each used once).

    ``rgb``, ``depth``: ``[(t s, path), ...]``; pairs with ``|Δt| > max_dt`` are dropped.
    Returns :class:`Associations` sorted by RGB time, with ``unmatched_rgb`` /
    ``unmatched_depth`` counts.
    """
    result = Associations()
    tr = np.array([t for t, _ in rgb], np.float64)  # [R]
    td = np.array([t for t, _ in depth], np.float64)  # [D]
    if len(tr) and len(td):
        d_order = np.argsort(td, kind="stable")
        td_sorted = td[d_order]
        lo = np.searchsorted(td_sorted, tr - max_dt, side="left")  # [R]
        hi = np.searchsorted(td_sorted, tr + max_dt, side="right")  # [R]
        counts = hi - lo
        ri = np.repeat(np.arange(len(tr)), counts)  # candidate pairs [C]
        offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        di = d_order[np.repeat(lo, counts) + offsets]
        dt = np.abs(tr[ri] - td[di])
        keep = dt <= max_dt
        ri, di, dt = ri[keep], di[keep], dt[keep]
        used_r = np.zeros(len(tr), bool)
        used_d = np.zeros(len(td), bool)
        pairs = []
        for c in np.lexsort((di, ri, dt)):  # smallest |Δt| first, ties by index
            r, d = int(ri[c]), int(di[c])
            if not used_r[r] and not used_d[d]:
                used_r[r] = used_d[d] = True
                pairs.append((r, d))
        pairs.sort(key=lambda p: (tr[p[0]], p[0]))
        result.extend((rgb[r], depth[d]) for r, d in pairs)
    result.unmatched_rgb = len(rgb) - len(result)
    result.unmatched_depth = len(depth) - len(result)
    return result


def read_trajectory(path: str | Path) -> np.ndarray:
    """Parse a TUM trajectory (``groundtruth.txt`` or an estimate): ``float64 [K, 8]`` rows
    ``t tx ty tz qx qy qz qw`` (s, m, quaternion last). Raises ``SlimsegError`` naming the file
    and line for a malformed line: not 8 numbers, a value that is not finite, or a quaternion
    whose norm is outside 0.5..2 (:func:`slimseg.data.value_checks.check_pose`)."""
    path = Path(path)
    rows = []
    for no, line in _read_lines(path):
        try:
            vals = [float(v) for v in line.split()]
            if len(vals) != 8:
                raise ValueError
        except ValueError:
            raise SlimsegError(
                f"{path}:{no}: expected 8 numbers 't tx ty tz qx qy qz qw', got {line!r}"
            ) from None
        check_pose(vals, f"{path}:{no}", f": {line!r}")
        rows.append(vals)
    return np.array(rows, np.float64).reshape(-1, 8)


def write_trajectory(path: str | Path, rows: np.ndarray) -> Path:
    """Write TUM rows ``[K, 8]`` (stamps with 6 decimals, the rest with 9), atomically."""
    lines = [
        f"{r[0]:.6f} " + " ".join(f"{v:.9f}" for v in r[1:])
        for r in np.asarray(rows).reshape(-1, 8)
    ]
    return write_text(path, "\n".join(lines) + ("\n" if lines else ""))


def depth_metres(raw: np.ndarray, depth_scale: float) -> np.ndarray:
    """An integer depth image ``[H, W]`` (``depth_scale`` units per metre, TUM: 5000) as
    ``float32`` metres (0 stays 0: no depth)."""
    return raw.astype(np.float32) / np.float32(depth_scale)


def mask_name(timestamp: float | str) -> str:
    """DynaSLAM-style mask-cache file name for an RGB frame: the RGB file's name, i.e. the
    timestamp with 6 decimals plus ``.png`` (``1305031102.175304`` → ``"1305031102.175304.png"``).

    A ``str`` timestamp is used verbatim (pass the stamp string from ``rgb.txt`` when it does
    not have 6 decimals).
    """
    stem = timestamp if isinstance(timestamp, str) else f"{float(timestamp):.6f}"
    return f"{stem}.png"


# camera.yaml: each value slimseg reads and the spellings it accepts for it (ORB-SLAM's settings
# files name them Camera.fx / Camera1.fx and DepthMapFactor / RGBD.DepthMapFactor)
CAMERA_KEYS: dict[str, tuple[str, ...]] = {
    "fx": ("fx", "Camera.fx", "Camera1.fx"),
    "fy": ("fy", "Camera.fy", "Camera1.fy"),
    "cx": ("cx", "Camera.cx", "Camera1.cx"),
    "cy": ("cy", "Camera.cy", "Camera1.cy"),
    "depth_scale": ("depth_scale", "DepthMapFactor", "RGBD.DepthMapFactor"),
}
# plain keys a camera file may carry that slimseg does not read (the synthetic sequences'
# extras, ORB-SLAM's depth threshold); any other plain key is a typo. Dotted keys are ORB-SLAM
# settings (ORBextractor.*, Viewer.*, ...) and pass unless they misspell a read one.
CAMERA_EXTRA_KEYS = ("width", "height", "distortion", "fps", "depth_offset_s", "ThDepth")


def _check_camera_keys(path: Path, cfg: dict) -> None:
    """Refuse a plain key that is not one of :data:`CAMERA_KEYS` / :data:`CAMERA_EXTRA_KEYS`
    (``fX``, ``depth_scal``) and a dotted key that is a read one in another case
    (``Camera.FX``); other dotted keys are ORB-SLAM settings slimseg does not read."""
    spellings = [k for names in CAMERA_KEYS.values() for k in names]
    plain = [k for k in (*spellings, *CAMERA_EXTRA_KEYS) if "." not in k]
    for key in map(str, cfg):
        if key in spellings or key in CAMERA_EXTRA_KEYS:
            continue
        if "." in key:
            close = [k for k in spellings if k.lower() == key.lower()]
            if not close:
                continue
        else:
            lower = {k.lower(): k for k in plain}
            close = [lower[k] for k in difflib.get_close_matches(key.lower(), lower, 1, 0.75)]
        hint = f" (did you mean {close[0]}?)" if close else ""
        reads = ", ".join(k for k in CAMERA_KEYS)
        raise SlimsegError(
            f"camera file {path}: unknown key {key!r}{hint}; it reads {reads} (or ORB-SLAM's "
            f"Camera.fx ...) and ignores {', '.join(CAMERA_EXTRA_KEYS)}"
        )


def read_camera(path: Path) -> dict[str, float]:
    """The values a ``camera.yaml`` gives, by :data:`CAMERA_KEYS` name (``fx fy cx cy
    depth_scale``; ORB-SLAM's ``Camera.fx`` / ``Camera1.fx`` and ``DepthMapFactor`` /
    ``RGBD.DepthMapFactor`` also accepted). ``SlimsegError`` naming the file and key for an
    unknown or misspelled key, a value that is not a finite number > 0, or a key given twice."""
    try:
        text = read_capped(path, "camera file", MAX_YAML_BYTES).decode("utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise SlimsegError(f"cannot read camera file {path}: {e}") from None
    lines = [ln for ln in text.splitlines() if not ln.startswith("%YAML")]
    cfg = load_yaml_text("\n".join(lines), f"cannot read camera file {path}") or {}
    if not isinstance(cfg, dict):
        raise SlimsegError(f"camera file {path}: expected a mapping of fx, fy, cx, cy")
    _check_camera_keys(path, cfg)
    vals: dict[str, float] = {}
    for name, spellings in CAMERA_KEYS.items():
        given = [k for k in spellings if k in cfg]
        if len(given) > 1:
            raise SlimsegError(f"camera file {path}: {name} given twice ({', '.join(given)})")
        if not given:
            continue
        v = cfg[given[0]]
        ok = isinstance(v, int | float) and not isinstance(v, bool)
        if not ok or not np.isfinite(v) or v <= 0:
            shown = printable(repr(v))
            shown = shown if len(shown) <= 60 else shown[:57] + "..."
            raise SlimsegError(f"camera file {path}: {given[0]} must be a number > 0, got {shown}")
        vals[name] = float(v)
    check_intrinsics({k: v for k, v in vals.items() if k != "depth_scale"}, f"camera file {path}")
    return vals


class TumSequence(PairedFrames):
    """A TUM-layout RGB-D sequence folder, a :class:`~slimseg.data.frame_source.FrameSource`.

    ``frames``: associated ``((t_rgb, rgb_path), (t_depth, depth_path))`` pairs (paths relative
    to ``root``); ``camera``: :class:`Camera` from ``camera.yaml`` if present, else the
    published calibration the folder name points at (``freiburg3`` → TUM fr3, ``bonn`` →
    Bonn; :mod:`slimseg.data.tum`), else TUM fr1; ``camera_source`` says which
    (``"camera.yaml"``, ``"tum-fr3 (folder name)"``, ``"tum-fr1 (default)"``). Raises
    ``SlimsegError`` when a list is missing or malformed or no frame pair associates.
    """

    def __init__(self, root: str | Path, max_dt: float = MAX_DT) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise SlimsegError(f"TUM sequence folder {self.root} does not exist")
        lists = {}
        for name in ("rgb.txt", "depth.txt"):
            p = self.root / name
            if not p.is_file():
                raise SlimsegError(f"TUM sequence {self.root}: missing {p}")
            lists[name] = read_list(p)
        self.frames: Associations = associate(lists["rgb.txt"], lists["depth.txt"], max_dt)
        if not self.frames:
            raise SlimsegError(
                f"TUM sequence {self.root} is empty: {len(lists['rgb.txt'])} rgb and "
                f"{len(lists['depth.txt'])} depth entries, no pair within {max_dt} s"
            )
        cam = self.root / "camera.yaml"
        given = read_camera(cam) if cam.is_file() else {}
        key = calibration_for(self.root)
        fallback = f"{key} (folder name)" if key else f"{DEFAULT} (default)"
        self.camera = Camera(
            **{**CALIBRATIONS[key or DEFAULT], "depth_scale": TUM_DEPTH_SCALE, **given}
        )
        self._scale_source = str(cam) if "depth_scale" in given else "the TUM default"
        from_file = [k for k in ("fx", "fy", "cx", "cy") if k in given]
        if len(from_file) == 4:
            self.camera_source = "camera.yaml"
        elif from_file:
            self.camera_source = f"camera.yaml ({', '.join(from_file)}), the rest {fallback}"
        else:
            self.camera_source = fallback
        if self.camera_source != "camera.yaml":
            log.info("sequence %s: intrinsics %s", self.root, self.camera_source)
        self._depth_checked = False
        self._frames_seen = FrameChecks(str(self.root))

    def camera_origin(self) -> str:
        """Where the intrinsics came from, the camera file named by its path."""
        source = self.camera_source
        if source == f"{DEFAULT} (default)":
            source = f"{DEFAULT} (the default: no camera.yaml, no known camera in the folder name)"
        return source.replace("camera.yaml", str(self.root / "camera.yaml"), 1)

    def load(self, i: int) -> Frame:
        """Frame ``i``: ``rgb uint8 [H, W, 3]`` (RGB order), ``depth_m float32 [H, W]`` metres
        (0 where invalid) and the RGB timestamp (s). Raises ``SlimsegError`` naming the file
        when it is missing or unreadable, and both files when their sizes differ."""
        (t_rgb, rgb_rel), (_, depth_rel) = self.frames[self.frame_index(i)]
        rgb_path, depth_path = self.root / rgb_rel, self.root / depth_rel
        bgr = _imread(rgb_path, cv2.IMREAD_COLOR)
        raw = _imread(depth_path, cv2.IMREAD_UNCHANGED)
        if raw.ndim != 2:
            raise SlimsegError(f"depth image {depth_path} has {raw.shape[2]} channels, expected 1")
        if raw.dtype != np.uint16:
            raise SlimsegError(
                f"depth image {depth_path} is {raw.dtype}, expected a 16-bit PNG (uint16, "
                f"{self.camera.depth_scale:g} units per metre): re-save the depth unscaled"
            )
        if raw.shape != bgr.shape[:2]:
            raise SlimsegError(
                f"size mismatch: {rgb_path} is {bgr.shape[1]}x{bgr.shape[0]} but "
                f"{depth_path} is {raw.shape[1]}x{raw.shape[0]}"
            )
        depth = depth_metres(raw, self.camera.depth_scale)
        depth[~np.isfinite(depth) | (depth < 0)] = 0.0
        self._frames_seen.check(bgr.shape[:2], depth, str(rgb_path))
        if not self._depth_checked:
            self._check_depth_scale(depth, depth_path)
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        return rgb, depth, t_rgb

    def _check_depth_scale(self, depth: np.ndarray, path: Path) -> None:
        """Refuse a ``depth_scale`` that puts the first loaded frame's median valid depth
        outside :data:`~slimseg.data.frame_source.DEPTH_RANGE_M` (e.g. millimetre depth read at
        TUM's 5000 per metre)."""
        median = implausible_median_depth(depth)
        if median is not None:
            lo, hi = DEPTH_RANGE_M
            raise SlimsegError(
                f"depth image {path}: median depth {median:.3g} m at depth_scale "
                f"{self.camera.depth_scale:g} (from {self._scale_source}) is outside "
                f"{lo}-{hi} m; set depth_scale in camera.yaml to the stored units per metre "
                "(TUM 5000, mm 1000)"
            )
        self._depth_checked = True


def _imread(path: Path, flags: int) -> np.ndarray:
    """The shared image decoder (``slimseg.data.images``), raising ``SlimsegError`` naming
    ``path`` instead of returning None."""
    if not path.is_file():
        raise SlimsegError(f"missing image file {path}")
    img = decode_file(path, flags)
    if img is None:
        raise SlimsegError(f"cannot decode image file {path}")
    return img
