"""A ROS recording read as an RGB-D sequence: a :class:`~slimseg.data.frame_source.FrameSource`
like a TUM folder (``frames``, ``camera``, ``load(i)``, ``fps``, ``close()``, ...); it holds the
recording open until closed.

Opening the bag reads only message headers (one pass, nothing decoded but the first
``camera_info``): the colour and depth header stamps are paired by the TUM rule
(:func:`~slimseg.data.tum.associate`, 0.02 s), frames without a partner counted. ``load(i)``
then streams: a cursor walks the bag in log-time order, keeping only messages read ahead of
the frame they belong to, so memory stays flat however long the recording (going back restarts
the cursor at that frame's log time). ``frames`` carries the names ``slimseg data bag2tum``
gives the files (``rgb/<stamp>.png``, ``depth/<stamp>.png``).

Intrinsics come from the ``camera_info`` topic (its distortion model named; frames are used as
recorded, not undistorted), else from ``--camera`` (a ``camera.yaml``), else TUM fr1's as for a
folder. Depth is decoded to metres by its encoding (:mod:`slimseg.data.bags.image_messages`); the
sequence's ``depth_scale`` is TUM's 5000 units per metre, what its depth is written at.
"""

from __future__ import annotations

import bisect
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slimseg.data.bags.header import COMPRESSED, Header
from slimseg.data.bags.image_messages import (
    colour_from_compressed,
    colour_from_image,
    depth_from_compressed,
    depth_from_image,
)
from slimseg.data.bags.reader import BagFile
from slimseg.data.bags.topics import TopicChoice, choose_topics
from slimseg.data.frame_source import DEPTH_RANGE_M, Frame, PairedFrames, implausible_median_depth
from slimseg.data.problems import ImageProblem
from slimseg.data.tum import (
    CALIBRATIONS,
    DEFAULT,
    MAX_DT,
    TUM_DEPTH_SCALE,
    Associations,
    Camera,
    associate,
    mask_name,
    read_camera,
)
from slimseg.data.value_checks import FrameChecks, check_intrinsics
from slimseg.errors import SlimsegError
from slimseg.utils.text import printable

log = logging.getLogger(__name__)

Key = tuple[str, int, int]  # (topic, log time ns, index among that topic's messages at that time)


@dataclass(frozen=True)
class BagOptions:
    """How to read a bag: topics (None: the only candidate), a ``camera.yaml`` for a bag
    without ``camera_info``, and the pairing tolerance (s)."""

    rgb_topic: str | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    camera: Path | None = None
    max_dt: float = MAX_DT

    def given(self) -> list[str]:
        """The command-line options set (``["--rgb-topic", ...]``)."""
        opts = {
            "--rgb-topic": self.rgb_topic,
            "--depth-topic": self.depth_topic,
            "--camera-info-topic": self.camera_info_topic,
            "--camera": self.camera,
        }
        return [k for k, v in opts.items() if v is not None]


class BagSequence(PairedFrames):
    """A bag as a sequence (see the module docstring). Raises ``SlimsegError`` (one line) for
    a missing or ambiguous topic, stamps going backwards, a ``camera_info`` without focal
    lengths, a first frame that does not decode, or no colour-depth pair (the recording
    closed again first)."""

    def __init__(self, path: str | Path, options: BagOptions = BagOptions()) -> None:
        self.root = Path(path)
        self.options = options
        self._bag = BagFile(self.root)
        try:
            self._open(options)
        except BaseException:  # a refused recording is closed before the error goes up
            self._bag.close()
            raise

    def _open(self, options: BagOptions) -> None:
        """Topics, the header index, the intrinsics, and frame 0 read once to check it."""
        self.topics: TopicChoice = choose_topics(
            str(self.root), self._bag.topics, options.rgb_topic, options.depth_topic,
            options.camera_info_topic, self._bag.held,
        )  # fmt: skip
        self._types = {t: self._bag.topics[t] for t in (self.topics.rgb, self.topics.depth)}
        self.profile = self._bag.profile(self.topics.rgb)  # how its colour topic is encoded
        info = self._index()
        self.camera, self.camera_source = self._intrinsics(info)
        # (w, h) the camera_info was calibrated at; 0 x 0 when it does not say
        self._info_size = (0, 0) if info is None else (int(info.width), int(info.height))
        self._cursor: object = None
        self._cursor_at = -1  # ordinal of the last message the cursor yielded
        self._ahead: dict[Key, bytes] = {}
        self._counts: dict[tuple[str, int], int] = {}  # the cursor's messages per (topic, time)
        self._cached: tuple[int, tuple[np.ndarray, np.ndarray, float]] | None = None
        self._frames_seen = FrameChecks(str(self.root))
        self.load(0)  # an unknown encoding, a size mismatch or a wrong depth unit fails here

    # --- index -------------------------------------------------------------------------
    def _index(self) -> object:
        """One pass over the headers: stamps, keys and ordinals; the first camera_info."""
        rgb_t, depth_t, info_t = self.topics.rgb, self.topics.depth, self.topics.info
        lists: dict[str, list[tuple[float, str]]] = {rgb_t: [], depth_t: []}
        self._key: dict[str, Key] = {}  # file name → message key
        self._ordinal: dict[Key, int] = {}
        self._place: dict[Key, int] = {}  # a message's index among its topic's messages
        self._times: list[int] = []  # log time of each colour/depth message, in bag order
        headers: dict[str, Header] = {}
        last: dict[str, Header] = {}
        seen: dict[tuple[str, int], int] = {}
        info = None
        wanted = [rgb_t, depth_t] + ([info_t] if info_t else [])
        for topic, t, raw in self._bag.messages(wanted):
            if topic == info_t:
                if info is None:
                    info = self._bag.decode(raw, self._bag.topics[topic], topic)
                continue
            h = self._bag.header(raw, topic, len(lists[topic]))
            prev = last.get(topic)
            if prev is not None and h.ns <= prev.ns:
                raise SlimsegError(
                    f"bag {self.root}: header stamps on {topic} go backwards or repeat at "
                    f"message {len(lists[topic]) + 1} ({prev.seconds:.9f} then {h.seconds:.9f} "
                    "s); re-stamp the recording"
                )
            last[topic] = h
            k = seen.get((topic, t), 0)
            seen[(topic, t)] = k + 1
            key = (topic, t, k)
            self._ordinal[key] = len(self._times)
            self._place[key] = len(lists[topic])
            self._times.append(t)
            name = ("rgb/" if topic == rgb_t else "depth/") + mask_name(h.seconds)
            if name in self._key:
                raise SlimsegError(
                    f"bag {self.root}: two messages on {topic} stamped {h.seconds:.6f} s "
                    "(within 1 microsecond); re-stamp the recording"
                )
            self._key[name] = key
            headers[name] = h
            lists[topic].append((h.seconds, name))
        if not lists[rgb_t]:
            raise SlimsegError(f"bag {self.root}: colour topic {rgb_t} has no messages")
        if not lists[depth_t]:
            raise SlimsegError(f"bag {self.root}: depth topic {depth_t} has no messages")
        self.frames: Associations = associate(lists[rgb_t], lists[depth_t], self.options.max_dt)
        if not self.frames:
            raise SlimsegError(
                f"bag {self.root}: no colour stamp on {rgb_t} has a depth stamp on {depth_t} "
                f"within {self.options.max_dt} s ({len(lists[rgb_t])} and "
                f"{len(lists[depth_t])} messages)"
            )
        self.headers: list[Header] = [headers[r] for (_, r), _ in self.frames]
        self._frame_of: dict[Key, int] = {}
        for i, ((_, r), (_, d)) in enumerate(self.frames):
            self._frame_of[self._key[r]] = i
            self._frame_of[self._key[d]] = i
        return info

    def _intrinsics(self, info: object) -> tuple[Camera, str]:
        if info is not None:
            k = [float(v) for v in (info.k if self._bag.cdr else info.K)]
            fx, fy, cx, cy = k[0], k[4], k[2], k[5]
            if not all(np.isfinite(v) and v > 0 for v in (fx, fy, cx, cy)):
                raise SlimsegError(
                    f"bag {self.root}: camera_info on {self.topics.info} has fx {fx:g}, fy "
                    f"{fy:g}, cx {cx:g}, cy {cy:g} (an uncalibrated camera); give intrinsics "
                    "with --camera camera.yaml"
                    + ("" if self.options.camera_info_topic else " or --camera-info-topic")
                )
            check_intrinsics(
                {"fx": fx, "fy": fy, "cx": cx, "cy": cy},
                f"bag {self.root}: camera_info on {printable(self.topics.info)}",
            )
            model = str(info.distortion_model) or "no model"
            return Camera(fx, fy, cx, cy, TUM_DEPTH_SCALE), (
                f"camera_info {self.topics.info} (distortion model {model}; frames used as "
                "recorded)"
            )
        cam = self.options.camera
        if cam is not None:
            given = read_camera(Path(cam))
            missing = [k for k in ("fx", "fy", "cx", "cy") if k not in given]
            if missing:
                raise SlimsegError(f"--camera {cam}: lacks {', '.join(missing)}")
            vals = {k: given[k] for k in ("fx", "fy", "cx", "cy")}
            return Camera(**vals, depth_scale=TUM_DEPTH_SCALE), str(cam)
        return (
            Camera(**CALIBRATIONS[DEFAULT], depth_scale=TUM_DEPTH_SCALE),
            f"{DEFAULT} (the default: the bag has no camera_info and no --camera was given)",
        )

    # --- the frame interface -----------------------------------------------------------
    def describe(self) -> str:
        """One line: the topics chosen (and why) and how the stamps paired, with every
        non-printable character of the recording's text escaped."""
        t, why = self.topics, self.topics.why
        parts = [f"colour {t.rgb} ({why['colour']})", f"depth {t.depth} ({why['depth']})"]
        if t.info:
            parts.append(f"camera_info {t.info} ({why['camera_info']})")
        f = self.frames
        return printable(  # topic names come from the recording: escaped for the terminal
            f"bag {self.root}: {', '.join(parts)}; {len(f)} frames paired within "
            f"{self.options.max_dt} s, {f.unmatched_rgb} colour and {f.unmatched_depth} depth "
            "messages without a partner"
        )

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` released the recording."""
        return self._bag.closed

    def close(self) -> None:
        """Release the bag file (the sequence cannot load frames afterwards)."""
        self._cursor = None
        self._ahead.clear()
        self._cached = None
        self._bag.close()

    def load(self, i: int) -> Frame:
        """Frame ``i``: ``rgb uint8 [H, W, 3]``, ``depth_m float32 [H, W]`` metres (0 where
        invalid) and the colour header stamp (s). ``SlimsegError`` naming the bag, topic and
        stamp when a message does not decode or the two sizes differ."""
        i = self.frame_index(i)
        if self.closed:
            raise SlimsegError(f"bag {self.root} was closed; open it again to read frames")
        if self._cached is not None and self._cached[0] == i:
            rgb, depth, t = self._cached[1]
            return rgb.copy(), depth.copy(), t
        (t_rgb, rgb_name), (_, depth_name) = self.frames[i]
        raws = self._fetch(i, (self._key[rgb_name], self._key[depth_name]))
        rgb = self._decode(raws[0], self.topics.rgb, t_rgb, self._key[rgb_name], colour=True)
        depth = self._decode(raws[1], self.topics.depth, t_rgb, self._key[depth_name], False)
        if depth.shape != rgb.shape[:2]:
            raise SlimsegError(
                f"bag {self.root}: at {t_rgb:.6f} s colour ({self.topics.rgb}) is "
                f"{rgb.shape[1]}x{rgb.shape[0]} but depth ({self.topics.depth}) is "
                f"{depth.shape[1]}x{depth.shape[0]}"
            )
        self._frames_seen.check(rgb.shape[:2], depth, f"bag {self.root} at {t_rgb:.6f} s")
        if self._cached is None:
            self._check_depth(depth)
            self._check_info_size(rgb.shape[1], rgb.shape[0])
        self._cached = (i, (rgb, depth, t_rgb))
        return rgb.copy(), depth.copy(), t_rgb

    def _decode(self, raw: bytes, topic: str, stamp: float, key: Key, colour: bool) -> np.ndarray:
        msgtype = self._types[topic]
        msg = self._bag.decode(raw, msgtype, topic, self._place[key])
        try:
            if msgtype == COMPRESSED:
                return colour_from_compressed(msg) if colour else depth_from_compressed(msg)
            return colour_from_image(msg) if colour else depth_from_image(msg)
        except (ValueError, ImageProblem) as e:  # ImageProblem: a header over the pixel cap
            kind = "colour" if colour else "depth"
            raise SlimsegError(
                f"bag {self.root}: {kind} topic {topic} at {stamp:.6f} s: {e}"
            ) from None

    def _check_depth(self, depth: np.ndarray) -> None:
        median = implausible_median_depth(depth)
        if median is not None:
            lo, hi = DEPTH_RANGE_M
            raise SlimsegError(
                f"bag {self.root}: depth on {self.topics.depth} has a median of "
                f"{median:.3g} m, outside {lo}-{hi} m: its encoding does not match its "
                "units (16UC1 must be millimetres, 32FC1 metres)"
            )

    def _check_info_size(self, w: int, h: int) -> None:
        """Refuse a ``camera_info`` calibrated at another size than the colour frames (the
        depth camera's, or another resolution's): its intrinsics would be wrong."""
        if self._info_size != (0, 0) and self._info_size != (w, h):
            iw, ih = self._info_size
            raise SlimsegError(
                f"bag {self.root}: camera_info {self.topics.info} is for {iw}x{ih} frames but "
                f"{self.topics.rgb} is {w}x{h}: name the colour camera's with "
                "--camera-info-topic, or give --camera camera.yaml"
            )

    def _fetch(self, i: int, keys: tuple[Key, Key]) -> list[bytes]:
        """The raw messages of ``keys`` (frame ``i``'s colour and depth), from what the
        cursor read ahead or by walking it on (restarted when it has passed them)."""
        for k in [k for k in self._ahead if self._frame_of[k] <= i and k not in keys]:
            del self._ahead[k]  # read ahead for a frame already served
        got = {k: self._ahead.pop(k) for k in keys if k in self._ahead}
        missing = [k for k in keys if k not in got]
        if missing and min(self._ordinal[k] for k in missing) <= self._cursor_at:
            start = min(k[1] for k in missing)
            self._cursor = self._bag.messages([self.topics.rgb, self.topics.depth], start)
            self._cursor_at = bisect.bisect_left(self._times, start) - 1
            self._ahead.clear()
            self._counts = {}
        elif self._cursor is None:
            self._cursor = self._bag.messages([self.topics.rgb, self.topics.depth])
            self._counts = {}
        while missing:
            step = next(self._cursor, None)
            if step is None:
                raise SlimsegError(f"bag {self.root}: ended before frame {i}'s messages")
            topic, t, raw = step
            k = self._counts.get((topic, t), 0)
            self._counts[(topic, t)] = k + 1
            key = (topic, t, k)
            self._cursor_at += 1
            if key in missing:
                got[key] = raw
                missing.remove(key)
            elif self._frame_of.get(key, -1) > i:
                self._ahead[key] = raw
        return [got[k] for k in keys]
