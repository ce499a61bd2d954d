"""The end-to-end export's gate checks something on an untrained model (issue #62): its raw graph
finds no detection at the gate's conf (0.25), so the gate also compares a twin graph baked at a
lower conf, on at least ``MIN_INSTANCES`` instances, NMS and mask product included."""

from __future__ import annotations

import re
from pathlib import Path

from slimseg.cli.main import main
from slimseg.deploy.end2end_parity import MIN_INSTANCES


def test_an_untrained_export_is_gated_on_50_instances(tmp_path: Path, capsys) -> None:
    out = tmp_path / "e2e.onnx"
    args = ["export", "--weights", "yolov8n-seg", "--nc", "3", "--imgsz", "160", "--end2end",
            "--quiet", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    printed = capsys.readouterr().out
    stats = {k: float(v) for k, v in re.findall(r"(end2end\w*/\w+) ([-\d.e+]+)", printed)}
    assert stats["end2end/detections"] == 0  # nothing at 0.25: the old gate checked nothing
    assert stats["end2end_low/detections"] >= MIN_INSTANCES, stats
    assert stats["end2end_low/fraction"] >= 0.95 and stats["end2end_low/min_mask_iou"] >= 0.9
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e2e.json", "e2e.onnx"]
