"""The track stage: masks that remember, between a frame's detections and the masking logic.

Per model frame (docs/tracking.md §2; ByteTrack, BoT-SORT, OC-SORT, CFP-SLAM):

1. **Predict.** The camera's motion ``H`` (background similarity, :mod:`camera_motion`) moves
   every track's box filter (:class:`~slimseg.dynamic.kalman.BoxKalman`) before its
   constant-velocity step; the track's last observed mask follows through the accumulated
   transform (camera motions, then the object's own velocity).
2. **Associate (BYTE).** Detections scoring ``>= high`` or emitted (above the masking
   threshold) against every track, then the rest down to ``low`` against the confirmed
   tracks left; cost 1 - mask IoU (box IoU without masks), objects of other classes never
   match; Hungarian assignment (:mod:`slimseg.dynamic.assignment`), gated. A detection is
   compared only with tracks whose predicted box it overlaps (box IoU >= 0.05), with the
   track's last mask shifted by its predicted centre motion (no warp); masks are warped only
   for emission (coast, carry).
3. **Update.** A match takes the detection's mask and box; an unmatched detection that is
   emitted (or scores ``>= new``) opens a tentative track; a tentative track that finds no
   detection on a model frame ends (ByteTrack's rule), so tentative tracks stay few. Only a
   track backed by a detection scoring ``>= new`` is confirmed (``min_hits`` matches, or one
   ``>= confirm``): a weak one is carried, never coasted.
4. **Coast.** A confirmed track without a match emits its predicted mask for up to
   ``max_coast`` frames, dilated per missed frame and cut to the track's depth band; its
   mobility is ``p · coast_decay^misses``, so Eq. 1 gives coasted masks up first.
5. **Moving probability.** Where the epipolar check runs, its decision on a tracked object
   updates the track's ``p`` (:class:`~slimseg.dynamic.track_belief.TrackBeliefs`); ``p`` relaxes
   to the class prior.

Every detection the per-frame logic would use (score above the masking threshold) is emitted
whether or not it matched, so recall can only go up; low-score detections matched to a
confirmed track (BYTE's second pass) and coasted masks are added. On the frames the model
skips (``dets`` None: ``--rate N``, a model on its own thread) every track the last
model frame saw (tentative ones too) and every confirmed track still coasting is carried, so
what the model found stays masked between its frames.
"""

from __future__ import annotations

import math
import time

import numpy as np

from slimseg.dynamic.assignment import linear_assignment
from slimseg.dynamic.camera_motion import CameraMotion
from slimseg.dynamic.kalman import BoxKalman
from slimseg.dynamic.mask_patch import (
    Patch,
    clip_patch,
    dilate_patch,
    patch_depth,
    patch_from_box,
    patch_from_mask,
    patch_iou,
    warp_patch,
    whole_pixel_shift,
)
from slimseg.dynamic.modes import FPS
from slimseg.dynamic.track_geometry import (
    box_iou,
    box_iou_matrix,
    median_depth,
    motion_scale,
    outside_share,
)
from slimseg.dynamic.track_settings import (
    CONFIRM_SCORE,
    IOU_HIGH,
    IOU_LOW,
    KEEP_FRAMES,
    MAX_OUTSIDE,
    MIN_DEPTH_SHARE,
    MIN_HITS,
    P_RELAX_S,
    TrackSettings,
)
from slimseg.dynamic.track_types import Emitted, Track
from slimseg.objects import SOURCE_CARRIED, SOURCE_COAST, SOURCE_DETECTION, Objects

STAGE_PARTS = ("motion", "lag", "predict", "associate", "warp", "update", "coast", "paste")
"""The stage's parts as timed (``Tracker.parts``): ORB matching + similarity fit and moving a
late model result into the frame (both timed by the caller), box filters and transforms,
association (IoU + Hungarian, without the warps), mask warps, track updates (filter), coasting
(dilation, depth gate, without the warps), the output masks."""
IOU_STRIDE = 2  # association counts mask overlaps on every 2nd row and column
SHIFT_TOLERANCE_PX = 1.0  # a predicted mask is shifted, not warped, when no corner moves more


class Tracker:
    """The stage's state over a sequence: call :meth:`step` once per frame in order."""

    def __init__(
        self,
        settings: TrackSettings,
        class_mobility: np.ndarray,
        *,
        fps: float = FPS,
        mover_prior: float = 0.0,
    ) -> None:
        """``class_mobility [K]``: class priors; only classes above ``mover_prior`` are
        tracked (Eq. 1 never masks the others: they pass through as detections)."""
        self.s = settings
        self.mover_prior = mover_prior
        self.priors = np.asarray(class_mobility, np.float32)
        self.dt = 1.0 / (fps if fps > 0 else FPS)
        self.tracks: list[Track] = []
        self._next_id = 1
        self._hw: tuple[int, int] | None = None
        self._box_only = False
        self.coasted = 0
        """predicted masks emitted so far (coasted or carried)"""
        self.frame_no = -1
        self.parts: dict[str, float] = dict.fromkeys(STAGE_PARTS, 0.0)
        """seconds spent per part of the stage (see :data:`STAGE_PARTS`), summed over frames"""

    @property
    def hw(self) -> tuple[int, int] | None:
        """Frame size of the sequence (None before the first frame)."""
        return self._hw

    def step(
        self,
        dets: Objects | None,
        motion: CameraMotion,
        emit_conf: float,
        depth_m: np.ndarray | None = None,
        lag: int = 0,
        own: dict[int, np.ndarray] | None = None,
    ) -> Objects:
        """Advance one frame. ``dets``: this frame's detections at a threshold at or below
        ``low`` (None: the model did not run on this frame); ``emit_conf``: the masking score
        threshold (detections above it are always emitted); ``depth_m [H, W]`` metres (0 =
        invalid) for the coasting depth gate (None: no gate); ``lag``: ``dets`` were computed
        that many frames ago (already moved by the camera motion since): a detection matched
        to a track is moved on by the track's own velocity times ``lag``; ``own``: track id
        → its object's measured ``(dx, dy)`` px since the previous frame (those tracks move
        by it instead of the camera motion and their velocity)."""
        t0 = time.perf_counter()
        if dets is None and self._hw is None:
            raise ValueError("the first frame of a sequence needs detections (the model runs)")
        self.frame_no += 1
        relax = math.exp(-self.dt / P_RELAX_S)
        scale = motion_scale(motion)
        own = own or {}
        for t in self.tracks:
            shift = own.get(t.id)
            centre = t.kf.centre
            t.kf.predict(motion, scale)
            if shift is not None:  # measured: where its ORB matches went
                t.kf.place(centre + shift)
                t.transform[:2] += np.outer(shift, t.transform[2])
                t.since_seen += 1
                t.p = float(t.prior + relax * (t.p - t.prior))
                continue
            if motion.ok:
                t.transform = motion.H @ t.transform
            v = t.kf.velocity
            t.transform[:2] += np.outer(v, t.transform[2])  # then the object's own velocity
            t.since_seen += 1
            t.p = float(t.prior + relax * (t.p - t.prior))
        t1 = time.perf_counter()
        self.parts["predict"] += t1 - t0
        if dets is None:
            objs = self._carry(depth_m, emit_conf)
        else:
            objs = self._associate(dets, emit_conf, depth_m, lag)
        t2 = time.perf_counter()
        frame = self._frame(objs, self._hw, None if dets is None else dets.masks)
        self.parts["paste"] += time.perf_counter() - t2
        return frame

    # -- model frames ------------------------------------------------------------------------

    def _associate(self, dets: Objects, emit_conf: float, depth_m, lag: int) -> list[Emitted]:
        s, hw = self.s, dets.hw
        self._hw, self._box_only = hw, dets.masks is None
        boxes = np.array(dets.boxes, np.float64).reshape(-1, 4)  # a copy: moved below
        scores = np.asarray(dets.scores, np.float64).reshape(-1)
        classes = np.asarray(dets.classes, int).reshape(-1)
        if dets.masks is None:  # a box-only model: the filled box is the object
            patches = [patch_from_box(b, hw) for b in boxes]
        else:
            patches = [patch_from_mask(m, b) for m, b in zip(dets.masks, boxes, strict=True)]
        movers = self.priors[classes] > self.mover_prior
        emitted = scores > emit_conf
        first = (scores >= s.high) | emitted
        high = np.flatnonzero(first & movers)
        low = np.flatnonzero((scores >= s.low) & ~first & movers)
        matched: dict[int, Track] = {}
        free = list(self.tracks)
        for idx, pool, gate in ((high, free, IOU_HIGH), (low, None, IOU_LOW)):
            pool = [t for t in free if t.confirmed] if pool is None else pool
            pairs = self._match(idx, pool, patches, boxes, classes, gate)
            for d, t in pairs:
                matched[d] = t
            used = {id(t) for _, t in pairs}
            free = [t for t in free if id(t) not in used]
        objs: list[Emitted] = []
        moved = set()
        own = dets.own_motion
        for d in range(len(boxes)):
            t = matched.get(d)
            pushed = not own[d]  # moved by its own motion already: no push
            if t is not None and lag > 0 and t.hits > 1 and pushed:  # late: the object moved on
                dx, dy = np.round(t.kf.velocity * lag).astype(int)
                if dx or dy:
                    p = patches[d]
                    patches[d] = clip_patch(p.moved(int(dy), int(dx)), hw)
                    boxes[d] = boxes[d] + [dx, dy, dx, dy]
                    moved.add(d)
            if t is not None:
                self._observe(t, patches[d], boxes[d], depth_m, scores[d])
            elif (emitted[d] or scores[d] >= s.new) and movers[d]:
                t = self._open(classes[d], scores[d], patches[d], boxes[d], depth_m)
            if t is None and scores[d] <= emit_conf:
                continue  # below the masking threshold and no track backs it
            if t is not None and scores[d] <= emit_conf and not t.confirmed:
                continue
            mob = float(self.priors[classes[d]]) if t is None else t.mobility(s.coast_decay)
            tid = -1 if t is None else t.id
            objs.append(Emitted(box=boxes[d], cls=int(classes[d]), patch=patches[d],
                                mobility=mob, track_id=tid, source=SOURCE_DETECTION,
                                score=float(scores[d]), det_index=d,
                                moved=d in moved))  # fmt: skip
        for t in free:
            t.misses += 1
            t.dead = t.dead or not t.confirmed  # a tentative track ends at its first miss
        objs += self._coast([t for t in free if t.confirmed], depth_m, SOURCE_COAST)
        self.tracks = [t for t in self.tracks if t.misses <= KEEP_FRAMES and not t.dead]
        return objs

    def _match(self, idx, pool, patches, boxes, classes, gate) -> list[tuple[int, Track]]:
        if len(idx) == 0 or not pool:
            return []
        t0, w0 = time.perf_counter(), self.parts["warp"]
        iou = np.zeros((len(idx), len(pool)))
        near = box_iou_matrix(boxes[idx], np.array([t.kf.box for t in pool]))
        near &= classes[idx][:, None] == np.array([t.cls for t in pool])[None]
        for i, j in zip(*np.nonzero(near), strict=True):
            d, t = idx[i], pool[j]
            if t.patch is not None:
                iou[i, j] = patch_iou(patches[d], self._shifted(t), IOU_STRIDE)
            else:
                iou[i, j] = box_iou(boxes[d], t.kf.box)
        rows, cols = linear_assignment(1.0 - iou)
        self.parts["associate"] += time.perf_counter() - t0 - (self.parts["warp"] - w0)
        return [(int(idx[r]), pool[c]) for r, c in zip(rows, cols, strict=True)
                if iou[r, c] >= gate]  # fmt: skip

    def _observe(self, t: Track, patch: Patch, box: np.ndarray, depth_m, score: float) -> None:
        t0 = time.perf_counter()
        t.kf.update(box)
        t.patch, t.transform, t.predicted, t.predicted_at = patch, np.eye(3), None, -1
        t.hits += 1
        t.misses = t.since_seen = 0
        t.strong = t.strong or score >= self.s.new
        t.confirmed = t.confirmed or (t.strong and t.hits >= MIN_HITS)
        t.depth_frame = depth_m  # its median is taken only if the track coasts
        self.parts["update"] += time.perf_counter() - t0

    def _open(self, cls, score, patch, box, depth_m) -> Track:
        t0 = time.perf_counter()
        prior = float(self.priors[cls])
        t = Track(self._next_id, int(cls), prior, prior, BoxKalman(box), patch)
        t.strong = score >= self.s.new
        t.confirmed = t.strong and (score >= CONFIRM_SCORE or MIN_HITS <= 1)
        t.depth_frame = depth_m
        self._next_id += 1
        self.tracks.append(t)
        self.parts["update"] += time.perf_counter() - t0
        return t

    # -- predictions -------------------------------------------------------------------------

    def previous_patches(self) -> tuple[list[Track], list[Patch]]:
        """The tracks with a mask in the previous frame (observed, or emitted as predicted
        there) and those masks, before :meth:`step` moves anything."""
        tracks, patches = [], []
        for t in self.tracks:
            p = t.patch if t.since_seen == 0 else t.predicted
            if p is None or (t.since_seen > 0 and t.predicted_at != self.frame_no):
                continue
            tracks.append(t)
            patches.append(p)
        return tracks, patches

    @staticmethod
    def _shifted(t: Track) -> Patch:
        """For association: the track's last observed mask moved by the whole-pixel shift of
        its centre under the accumulated transform (no warp: between model frames rotation
        and scale change a mask far less than the association gates tolerate)."""
        p = t.patch
        if t.since_seen == 0:
            return p
        h, w = p.mask.shape
        cx, cy = p.x0 + w / 2, p.y0 + h / 2
        m = t.transform
        z = m[2, 0] * cx + m[2, 1] * cy + m[2, 2]
        dx = (m[0, 0] * cx + m[0, 1] * cy + m[0, 2]) / z - cx
        dy = (m[1, 0] * cx + m[1, 1] * cy + m[1, 2]) / z - cy
        return p.moved(round(dy), round(dx))

    def _predicted(self, t: Track) -> Patch | None:
        """The track's last observed mask moved into this frame (computed once per frame, and
        only for the tracks that need it); None for box-only tracks."""
        if t.patch is None:
            return None
        if t.predicted_at != self.frame_no:
            t0 = time.perf_counter()
            shift = None
            if t.since_seen > 0:
                shift = whole_pixel_shift(t.patch, t.transform, SHIFT_TOLERANCE_PX)
            if t.since_seen == 0:
                t.predicted = t.patch
            elif shift is not None:  # a shift is as good as a warp here, and costs nothing
                t.predicted = clip_patch(t.patch.moved(*shift), self._hw)
            else:
                t.predicted = warp_patch(t.patch, t.transform, self._hw)
            t.predicted_at = self.frame_no
            self.parts["warp"] += time.perf_counter() - t0
        return t.predicted

    @staticmethod
    def _depth(t: Track) -> float:
        """The track's depth (median under its last observed mask), taken when first needed."""
        if t.depth_frame is not None and t.patch is not None:
            t.depth_m = median_depth(t.patch, t.depth_frame, t.depth_m)
        t.depth_frame = None
        return t.depth_m

    def _carry(self, depth_m, emit_conf) -> list[Emitted]:
        """A frame the model skipped: every live track is carried (tentative tracks are only
        alive until the next model frame misses them; confirmed ones coast up to K misses)."""
        objs = self._coast(list(self.tracks), depth_m, SOURCE_CARRIED)
        self.tracks = [t for t in self.tracks if not t.dead]
        return objs

    def _coast(self, tracks: list[Track], depth_m, source: str) -> list[Emitted]:
        """Emit the predicted masks of ``tracks`` that pass the guards (the rest are ended)."""
        s, hw, objs = self.s, self._hw, []
        t0, w0 = time.perf_counter(), self.parts["warp"]
        for t in tracks:
            if t.misses > s.max_coast:  # carried frames keep the misses of the last model frame
                continue
            box = t.kf.box
            if outside_share(box, hw) > MAX_OUTSIDE:
                t.dead = True
                continue
            if t.patch is None:
                patch = patch_from_box(box, hw)
            else:
                patch = dilate_patch(self._predicted(t), s.coast_dilate_px * t.since_seen, hw)
            gate = t.misses > 0  # a track the last model frame saw is only carried: no gate
            if gate and depth_m is not None and s.depth_band_m > 0 and self._depth(t) > 0:
                d = patch_depth(patch, depth_m)
                known = patch.mask & (d > 0)
                near = known & (np.abs(d - t.depth_m) <= s.depth_band_m)
                if known.sum() and near.sum() < MIN_DEPTH_SHARE * known.sum():
                    t.dead = True
                    continue
                patch = Patch(patch.y0, patch.x0, patch.mask & (near | (d <= 0)))
            if patch.area == 0:
                continue
            self.coasted += 1
            objs.append(Emitted(box=patch.box if t.patch is not None else box, cls=t.cls,
                                patch=patch, mobility=t.mobility(s.coast_decay), track_id=t.id,
                                source=source, misses=t.misses))  # fmt: skip
        self.parts["coast"] += time.perf_counter() - t0 - (self.parts["warp"] - w0)
        return objs

    def _frame(self, objs: list[Emitted], hw, det_masks) -> Objects:
        n = len(objs)
        boxes = np.array([o.box for o in objs], np.float32).reshape(n, 4)
        masks = None
        if not self._box_only:
            masks = np.zeros((n, *hw), bool)
            for k, o in enumerate(objs):  # a detection's own full mask needs no pasting
                own = o.det_index >= 0 and not o.moved
                masks[k] = det_masks[o.det_index] if own else o.patch.paste(hw)
        return Objects(
            boxes=boxes,
            scores=np.array([o.score for o in objs], np.float32),
            classes=np.array([o.cls for o in objs], np.int64),
            masks=masks,
            hw=hw,
            mobility=np.array([o.mobility for o in objs], np.float32),
            track_ids=np.array([o.track_id for o in objs], np.int64),
            source=np.array([o.source for o in objs], object),
            misses=np.array([o.misses for o in objs], np.int64),
            det_index=np.array([o.det_index for o in objs], np.int64),
        )
