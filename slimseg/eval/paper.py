"""Published numbers we compare against (data, quoted from the papers; see docs/papers.md §1)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PaperRow:
    """One row of the substation paper's Table II (20 classes, 640 px, 500 epochs)."""

    box_map: float
    seg_map: float
    gflops: float
    gradients_m: float
    params_m: float


# Table II of the substation-robot paper; keys are our variant names.
TABLE2 = {
    "yolov8s-seg": PaperRow(46.2, 39.5, 42.7, 11.8, 11.8),
    "yolov8s-seg-rep": PaperRow(46.1, 39.8, 40.8, 10.1, 12.2),
    "yolov8s-seg-gs": PaperRow(46.7, 40.1, 39.4, 10.9, 10.9),
    "yolov8s-seg-gs-rep": PaperRow(46.8, 40.3, 37.4, 9.2, 10.2),
}
TABLE2_NUM_CLASSES = 20
TABLE2_IMGSZ = 640


# Substation paper, Table III: ATE RMSE / std (m) on TUM fr3 dynamic sequences, real
# recordings, official ORB vocabulary. sequence -> (ORB-SLAM3 rmse, std, method rmse, std)
TABLE3_ATE: dict[str, tuple[float, float, float, float]] = {
    "fr3/walking_xyz": (0.2686, 0.1095, 0.0179, 0.0084),
    "fr3/walking_static": (0.0174, 0.0103, 0.0081, 0.0034),
    "fr3/walking_half": (0.1759, 0.0683, 0.0247, 0.0124),
    "fr3/walking_rpy": (0.1507, 0.0681, 0.0816, 0.0470),
}
# YOLO-SLAM's ablation on fr3/walking_xyz, ATE RMSE (m): configuration -> value
YOLO_SLAM_WALKING_XYZ_ATE: dict[str, float] = {
    "ORB-SLAM2": 0.7521,
    "boxes only": 0.0159,
    "depth-RANSAC only": 0.1437,
    "boxes + depth-RANSAC": 0.0146,
}
