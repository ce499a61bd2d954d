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
