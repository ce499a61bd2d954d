"""A Rerun recording (``.rrd``) of what the masking did, frame by frame (``--rerun FILE.rrd``
on ``slimseg dynamic`` and ``slimseg predict --track``; the ``slimseg[viz]`` extra,
``rerun-sdk``, imported only here and only when asked for).

Per frame, on the ``frame`` (index) and ``stamp`` (the colour header stamp) timelines:

- ``camera/image``: the colour frame (``Image``, raw: Rerun's web viewer in a headless browser
  never decoded a JPEG-compressed one);
  ``camera/depth``: depth (``DepthImage``, ``uint16`` at :data:`DEPTH_UNITS` per metre; not for
  ``predict``, which has none).
- ``camera/image/dynamic_mask``: the dynamic mask as a ``SegmentationImage``, each masked
  pixel the class id + 1 of the object whose mask covers it, :func:`unclaimed` where only the
  dilation reaches; class names and colours in the ``AnnotationContext`` logged once at ``/``.
- ``camera/image/objects``: the judged objects' boxes (``Boxes2D``), labelled ``#<track id>
  <class> p <moving probability>``, coloured by class.
- ``camera/image/keypoints/static`` and ``.../dynamic``: the ORB keypoints kept and dropped
  (``Points2D``, green and red).
- ``camera/image/ground_truth``: with ``truth`` (a sequence's ``dynamic/`` folder), its
  ground-truth dynamic mask (``SegmentationImage``, id :func:`truth_id`, amber), shown over the
  frame in a view of its own beside the main one.
- ``timing/<part>_ms``: the frame's milliseconds by part (``Scalars``: model, features,
  track, logic, latency).

The file is written under a temporary name beside ``FILE.rrd`` and renamed into place by
:meth:`RerunFrames.close` (:func:`finish`); a run that fails leaves nothing.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.images import decode_file
from slimseg.data.tum import mask_name
from slimseg.data.visualize import class_color
from slimseg.dynamic.masked_frame import MaskedFrame
from slimseg.errors import SlimsegError
from slimseg.sequence.mask_bag import object_labels
from slimseg.utils.atomic import stage_name
from slimseg.utils.decode_boundary import reason
from slimseg.utils.outputs import claim_file
from slimseg.utils.text import printable

log = logging.getLogger(__name__)

VIZ_HINT = "pip install 'slimseg[viz]'"
RRD_MAGIC = b"RRF"  # what every .rrd begins with (RRF0, RRF2, ...)
STATIC_COLOUR = (40, 220, 60)
DYNAMIC_COLOUR = (255, 40, 40)
TIMING_PARTS = ("model", "features", "track", "logic", "latency")
TRUTH = "ground_truth"  # entity (under camera/image) of a sequence's ground-truth dynamic mask
DEPTH_UNITS = 5000.0  # depth as uint16 at TUM's 5000 per metre (0.2 mm, up to 13.1 m)


def require_rerun(option: str = "--rerun") -> None:
    """``SlimsegError`` naming the extra when ``rerun-sdk`` is missing."""
    try:
        import rerun  # noqa: F401
    except ImportError:
        raise SlimsegError(f"{option} writes a Rerun recording: {VIZ_HINT}") from None


def is_rrd(path: Path) -> bool:
    """``path`` begins as a Rerun recording does (one slimseg may replace)."""
    try:
        with path.open("rb") as f:
            return f.read(3) == RRD_MAGIC
    except OSError:
        return False


def check_rrd_path(path: str | Path, option: str = "--rerun") -> Path:
    """``path`` checked before any work: a ``.rrd`` name, not a folder, and not a file of
    another kind (an earlier recording is replaced)."""
    path = Path(path)
    if path.suffix.lower() != ".rrd":
        raise SlimsegError(f"{option} {path}: a Rerun recording is a .rrd file")
    claim_file(path, option, is_rrd, "Rerun recording")
    require_rerun(option)
    return path


class RerunRecording:
    """A ``RecordingStream`` saving to a staged name: :meth:`seal` flushes and closes it in its
    stage (refused in one line, the stage removed, when it cannot be finished: a full disk, a
    read-only folder), :meth:`finish` seals it and renames it to ``path``, :meth:`discard`
    drops it."""

    def __init__(self, path: Path, application: str) -> None:
        import rerun as rr

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stage = self.path.with_name(stage_name(self.path.name))
        self.rr = rr
        self.sealed = False
        try:
            self.rec = rr.RecordingStream(application_id=application)
            self.rec.save(str(self._stage))
        except Exception as e:  # rerun's own errors (a RuntimeError naming the OS error)
            self._stage.unlink(missing_ok=True)
            raise SlimsegError(f"--rerun {printable(self.path)}: cannot write the recording: "
                               f"{reason(e)}") from None  # fmt: skip

    def seal(self) -> None:
        """Everything logged flushed into the stage and the stream closed (once)."""
        if self.sealed:
            return
        try:
            self.rec.flush()
            self.rec.disconnect()
            if self._stage.stat().st_size == 0:
                raise OSError("nothing was written")
        except Exception as e:  # rerun's file writer failing (disk full), or no file at all
            self._stage.unlink(missing_ok=True)
            raise SlimsegError(f"--rerun {printable(self.path)}: the recording could not be "
                               f"finished: {reason(e)}") from None  # fmt: skip
        self.sealed = True

    def finish(self) -> Path:
        self.seal()
        os.replace(self._stage, self.path)
        return self.path

    def discard(self) -> None:
        try:
            self.rec.disconnect()
        except Exception:  # the stream failed already: nothing left to close
            log.debug("closing the Rerun stream of %s failed", self.path, exc_info=True)
        self._stage.unlink(missing_ok=True)


def plain_logs() -> None:
    """Keep rerun's own log lines free of colour codes when stderr is not a terminal (its
    logger honours ``NO_COLOR`` / ``CLICOLOR``): set before rerun is first imported. A
    process-wide setting: the CLI calls it (:func:`slimseg.cli.rerun_args.rerun_path`), the
    library never does."""
    if not sys.stderr.isatty():
        os.environ.setdefault("NO_COLOR", "1")
        os.environ.setdefault("CLICOLOR", "0")


def annotation_context(rr: object, names: list[str]) -> object:
    """Id 0 static (transparent), class ``c`` as ``c + 1`` in its colour, :func:`unclaimed`
    for the dilation's pixels, :func:`truth_id` for the ground truth's."""
    infos = [rr.AnnotationInfo(id=0, label="static", color=(0, 0, 0, 0))]
    infos += [rr.AnnotationInfo(id=c + 1, label=n, color=class_color(c)) for c, n in
              enumerate(names)]  # fmt: skip
    infos.append(rr.AnnotationInfo(id=truth_id(names), label="ground truth (dynamic)",
                                   color=(255, 200, 0)))  # fmt: skip
    infos.append(rr.AnnotationInfo(id=unclaimed(names), label="dynamic (dilation)",
                                   color=(255, 255, 255)))  # fmt: skip
    return rr.AnnotationContext(infos)


def truth_id(names: list[str]) -> int:
    """The segmentation id of a ground-truth dynamic pixel (``camera/image/ground_truth``)."""
    return len(names) + 2


def unclaimed(names: list[str]) -> int:
    """The segmentation id of masked pixels no object's mask covers."""
    return len(names) + 1


def frames_layout(truth: bool = False) -> object:
    """The viewer's opening layout: the frame with mask, boxes and keypoints large; beside it
    depth, the frame with the ground-truth mask (``truth``) and every timing series in one
    plot; panels folded."""
    import rerun.blueprint as rrb

    side = [rrb.Spatial2DView(origin="camera/depth", name="depth (m)")]
    if truth:
        side.append(rrb.Spatial2DView(origin="camera/image", name="ground-truth dynamic mask",
                                      contents=["+ $origin", f"+ $origin/{TRUTH}"]))  # fmt: skip
    side.append(rrb.TimeSeriesView(origin="timing", name="ms per frame"))
    main = rrb.Spatial2DView(origin="camera/image", name="frame: dynamic mask, objects, keypoints",
                             contents=["+ $origin/**", f"- $origin/{TRUTH}"])  # fmt: skip
    return rrb.Blueprint(
        rrb.Horizontal(main, rrb.Vertical(*side), column_shares=[2, 1]), collapse_panels=True
    )


def class_map(f: MaskedFrame, n_classes: int) -> np.ndarray:
    """``uint16 [H, W]`` (logged as ``uint8`` when the ids fit): 0 outside the dynamic mask,
    the covering object's class + 1 inside (its instance mask, or its box for a box-only model),
    ``n_classes + 1`` elsewhere in it."""
    mask = f.mask > 0
    seg = np.zeros(mask.shape, np.uint16)
    obj = f.objects
    h, w = mask.shape
    for k in range(len(obj)):
        if obj.masks is not None:
            region = obj.masks[k]
        else:
            x0, y0, x1, y1 = np.clip(np.round(obj.boxes[k]), 0, [w, h, w, h]).astype(int)
            region = np.zeros_like(mask)
            region[y0:y1, x0:x1] = True
        seg[region & mask & (seg == 0)] = int(obj.classes[k]) + 1
    seg[mask & (seg == 0)] = n_classes + 1
    return seg


class RerunFrames(RerunRecording):
    """Per-frame logging (see the module docstring); an observer of
    :func:`~slimseg.sequence.sequence_run.run_sequence`: call it with each frame's outcome."""

    def __init__(
        self, path: Path, names: list[str], application: str, truth: Path | None = None
    ) -> None:
        super().__init__(path, application)
        self.names = list(names)
        self.truth = truth
        self.frames = 0
        self.rec.log("/", annotation_context(self.rr, self.names), static=True)
        self.rec.send_blueprint(frames_layout(truth is not None))

    def __call__(self, f: MaskedFrame, rgb: np.ndarray, depth: np.ndarray | None) -> None:
        rr, rec = self.rr, self.rec
        rec.set_time("frame", sequence=self.frames)
        rec.set_time("stamp", timestamp=f.stamp)
        rec.log("camera/image", rr.Image(rgb))
        if depth is not None:
            units = np.clip(np.round(depth * DEPTH_UNITS), 0, 65535).astype(np.uint16)
            rec.log("camera/depth", rr.DepthImage(units, meter=DEPTH_UNITS))
        seg = class_map(f, len(self.names))
        small = seg.max(initial=0) < 256
        rec.log("camera/image/dynamic_mask",
                rr.SegmentationImage(seg.astype(np.uint8) if small else seg))  # fmt: skip
        obj = f.objects
        rec.log("camera/image/objects", rr.Boxes2D(
            array=np.asarray(obj.boxes, np.float32).reshape(-1, 4),
            array_format=rr.Box2DFormat.XYXY, labels=object_labels(obj, self.names),
            class_ids=np.asarray(obj.classes, np.int64) + 1,
        ))  # fmt: skip
        kps, dyn = np.asarray(f.keypoints).reshape(-1, 2), np.asarray(f.dynamic, bool)
        rec.log("camera/image/keypoints/static", rr.Points2D(kps[~dyn], colors=STATIC_COLOUR))
        rec.log("camera/image/keypoints/dynamic", rr.Points2D(kps[dyn], colors=DYNAMIC_COLOUR))
        for part in TIMING_PARTS:
            rec.log(f"timing/{part}_ms", rr.Scalars(float(getattr(f.timing, part))))
        if self.truth is not None:
            gt = decode_file(self.truth / mask_name(f.stamp), cv2.IMREAD_GRAYSCALE)
            if gt is not None:  # a frame without one is left out (as the scores do)
                ids = np.where(gt > 0, truth_id(self.names), 0).astype(np.uint8)
                rec.log(f"camera/image/{TRUTH}", rr.SegmentationImage(ids))
        self.frames += 1
