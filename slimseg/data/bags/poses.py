"""Ground truth for a sequence: a TUM ``groundtruth.txt`` (the folder's own, or one given with
``--groundtruth``), or a pose topic of a bag: ``geometry_msgs/PoseStamped``,
``nav_msgs/Odometry`` or ``tf`` (``tf2_msgs/TFMessage``, the transform whose child frame is
``--pose-frame``, or the only child frame on the topic).

Rows are TUM's ``t tx ty tz qx qy qz qw`` (header stamps in s), sorted by time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slimseg.data.bags.header import ODOMETRY, POSE, TF, Header
from slimseg.data.bags.reader import BagFile, is_bag
from slimseg.data.tum import read_trajectory
from slimseg.data.value_checks import check_pose
from slimseg.errors import SlimsegError
from slimseg.utils.text import printable

POSE_TYPES = (POSE, ODOMETRY, TF)
MIN_POSES = 3  # an ATE needs at least three poses to align


def read_poses(bag: str | Path, topic: str, child_frame: str | None = None) -> np.ndarray:
    """The poses on ``topic`` of ``bag`` as TUM rows ``float64 [K, 8]`` (see the module
    docstring). ``SlimsegError`` for a missing topic, a type that is no pose, or a ``tf``
    topic with several child frames and none chosen."""
    rows: list[list[float]] = []
    with BagFile(bag) as f:
        kind = f.topics.get(topic)
        if kind is None:
            poses = [t for t, ty in f.topics.items() if ty in POSE_TYPES]
            raise SlimsegError(
                f"--pose-topic {topic}: bag {bag} has no such topic; pose topics: "
                f"{', '.join(sorted(poses)) or 'none'}"
            )
        if kind not in POSE_TYPES:
            raise SlimsegError(
                f"--pose-topic {topic} carries {kind}, expected one of {', '.join(POSE_TYPES)}"
            )
        children: set[str] = set()
        for index, (_, _, raw) in enumerate(f.messages([topic])):
            msg = f.decode(raw, kind, topic)
            where = f"bag {bag}: message {index} on {printable(topic)}"
            if kind == TF:
                for tr in msg.transforms:
                    children.add(tr.child_frame_id)
                    if child_frame is None or tr.child_frame_id == child_frame:
                        t, r = tr.transform.translation, tr.transform.rotation
                        rows.append(_row(tr.header, t, r, where))
                continue
            pose = msg.pose.pose if kind == ODOMETRY else msg.pose
            rows.append(_row(msg.header, pose.position, pose.orientation, where))
    if kind == TF and child_frame is None and len(children) > 1:
        raise SlimsegError(
            f"--pose-topic {topic} holds transforms of {len(children)} child frames "
            f"({', '.join(sorted(children))}): choose one with --pose-frame"
        )
    if kind == TF and child_frame is not None and child_frame not in children:
        raise SlimsegError(
            f"--pose-frame {child_frame}: no transform on {topic} has that child frame "
            f"(it has {', '.join(sorted(children)) or 'none'})"
        )
    out = np.array(rows, np.float64).reshape(-1, 8)
    return out[np.argsort(out[:, 0], kind="stable")]


def _row(header: object, t: object, q: object, where: str) -> list[float]:
    """One TUM row, checked (:func:`~slimseg.data.tum.check_pose`: finite, a usable
    quaternion), ``SlimsegError`` naming ``where`` (the bag, message index and topic)."""
    stamp = Header(int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec), "")
    row = [stamp.seconds, t.x, t.y, t.z, q.x, q.y, q.z, q.w]
    check_pose(row, where)
    return row


def ground_truth(
    root: Path,
    groundtruth: Path | None = None,
    pose_topic: str | None = None,
    pose_frame: str | None = None,
) -> np.ndarray:
    """The ground-truth rows ``[K, 8]`` of the sequence at ``root``: ``groundtruth`` (a TUM
    file), else ``pose_topic`` of the bag, else the folder's ``groundtruth.txt``. At least
    :data:`MIN_POSES`, else a one-line error naming the source."""
    if groundtruth is not None and pose_topic is not None:
        raise SlimsegError("give --groundtruth FILE or --pose-topic TOPIC, not both")
    if pose_frame is not None and pose_topic is None:
        raise SlimsegError("--pose-frame chooses a tf child frame: give --pose-topic too")
    if pose_topic is not None:
        if not is_bag(root):
            raise SlimsegError(f"--pose-topic needs a bag --sequence; {root} is a folder")
        gt, source = read_poses(root, pose_topic, pose_frame), f"{pose_topic} of {root}"
    else:
        path = groundtruth
        if path is None:
            if is_bag(root):
                raise SlimsegError(
                    f"bag {root} holds no groundtruth.txt: give --groundtruth FILE (TUM) or "
                    "--pose-topic TOPIC"
                )
            path = root / "groundtruth.txt"
        if not Path(path).is_file():
            raise SlimsegError(f"{path} is missing: a trajectory cannot be scored without it")
        gt, source = read_trajectory(path), str(path)
    if len(gt) < MIN_POSES:
        raise SlimsegError(f"{source} has {len(gt)} poses: need {MIN_POSES} or more")
    why = degenerate(gt[:, 1:4])
    if why:
        raise SlimsegError(
            f"{source}: the ground truth {why}, so no trajectory can be aligned to it (the ATE "
            "needs a camera path that spans a plane)"
        )
    return gt


def degenerate(positions: np.ndarray) -> str:
    """Why ``positions [K, 3]`` cannot anchor a rigid alignment (empty: they can): fewer than
    :data:`MIN_POSES` distinct positions, or all on one line (Umeyama's covariance then has
    rank < 2)."""
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    distinct = len(np.unique(p, axis=0))
    if distinct < MIN_POSES:
        return f"has {distinct} distinct position{'s' * (distinct != 1)}"
    s = np.linalg.svd(p - p.mean(0), compute_uv=False)
    if s[1] <= max(1e-9 * s[0], 1e-12):
        return "has all its positions on one line"
    return ""
