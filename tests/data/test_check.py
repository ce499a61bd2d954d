"""slimseg data check: one sample per bad-input kind, each reported with its kind and file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.cli import data_coco
from slimseg.data.check import check_dataset

H, W = 16, 24
GOOD_POLY = [[2, 2, 10, 2, 10, 10, 2, 10]]


def run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    data_coco.add_parsers(parser.add_subparsers(dest="action", required=True))
    args = parser.parse_args(argv)
    return args.run(args)


def build(root: Path, bad: bool = True) -> Path:
    """``root/annotations.json`` + ``root/images/``; with ``bad``, one image per problem."""
    img_dir = root / "images"
    img_dir.mkdir(parents=True)
    color = np.full((H, W, 3), 90, np.uint8)
    files: dict[str, np.ndarray | bytes | None] = {"good.png": color}
    if bad:
        files |= {
            "missing.jpg": None,
            "corrupt.jpg": b"\xff\xd8\xff garbage, not a jpeg",
            "gray.png": np.full((H, W), 90, np.uint8),
            "rgba.png": np.full((H, W, 4), 90, np.uint8),
            "deep.png": np.full((H, W, 3), 9000, np.uint16),
            "few.png": color,
            "zero.png": color,
            "outside.png": color,
            "unknown.png": color,
            "dupimg.png": color,
            "dupimg2.png": color,
            "dupann.png": color,
            "size.png": np.zeros((H + 2, W, 3), np.uint8),
        }
    images, anns = [], []
    for i, (name, content) in enumerate(files.items(), start=1):
        if isinstance(content, np.ndarray):
            cv2.imwrite(str(img_dir / name), content)
        elif isinstance(content, bytes):
            (img_dir / name).write_bytes(content)
        images.append({"id": i, "file_name": name, "width": W, "height": H})
        anns.append(
            {"id": 100 + i, "image_id": i, "category_id": 1, "iscrowd": 0}
            | {"segmentation": GOOD_POLY, "bbox": [2, 2, 8, 8]}
        )
    if bad:
        ids = {im["file_name"]: im["id"] for im in images}
        images[ids["dupimg2.png"] - 1]["id"] = ids["dupimg.png"]
        anns[ids["dupimg2.png"] - 1]["image_id"] = ids["dupimg.png"]
        extra = {
            "few.png": {"segmentation": [[1, 1, 5, 5]], "bbox": [1, 1, 4, 4]},
            "zero.png": {"segmentation": [[1, 1, 5, 5, 9, 9]], "bbox": [1, 1, 8, 8]},
            "outside.png": {"segmentation": GOOD_POLY, "bbox": [20, 10, 10, 10]},
            "unknown.png": {"segmentation": GOOD_POLY, "category_id": 42},
        }
        for name, change in extra.items():
            anns.append({"id": 500 + len(anns), "image_id": ids[name], "category_id": 1} | change)
        anns.append({**anns[ids["dupann.png"] - 1], "segmentation": [[0, 0, 4, 0, 4, 4]]})
    data = {"images": images, "annotations": anns, "categories": [{"id": 1, "name": "person"}]}
    (root / "annotations.json").write_text(json.dumps(data))
    return root


EXPECTED = {
    "missing_image": "missing.jpg",
    "unreadable_image": "corrupt.jpg",
    "grayscale_image": "gray.png",
    "rgba_image": "rgba.png",
    "16bit_image": "deep.png",
    "polygon_few_points": "few.png",
    "polygon_zero_area": "zero.png",
    "box_clipped": "outside.png",
    "unknown_category": "unknown.png",
    "duplicate_image_id": "dupimg2.png",
    "duplicate_annotation_id": "dupann.png",
    "size_mismatch": "size.png",
}
ERRORS = {
    "missing_image",
    "unreadable_image",
    "unknown_category",
    "duplicate_image_id",
    "duplicate_annotation_id",
    "size_mismatch",
}


def test_every_kind_reported_with_its_file(tmp_path: Path) -> None:
    report = check_dataset(build(tmp_path / "ds"), progress=False)
    kinds = report.kinds()
    for kind, name in EXPECTED.items():
        assert kinds.get(kind) == 1, (kind, kinds)
        files = report.files(kind)
        assert len(files) == 1 and files[0].startswith(name), (kind, files)
    assert report.files("size_mismatch") == ["size.png (json 24x16, file 24x18)"]
    assert report.errors == len(ERRORS) and report.warnings == len(EXPECTED) - len(ERRORS)
    assert not report.ok
    text = report.format()
    for kind in EXPECTED:
        assert kind in text
    assert "FAILED: 6 errors, 6 warnings" in text
    rows = {r[2]: r for r in report.rows()}
    assert all(rows[k][1] == "error" for k in ERRORS)
    assert rows["grayscale_image"][1] == "warning"


def test_clean_dataset_passes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = build(tmp_path / "ds", bad=False)
    report = check_dataset(root / "annotations.json", progress=False)  # json + sibling images/
    assert report.ok and report.errors == 0 and report.warnings == 0
    assert run_cli(["check", str(root), "--quiet"]) == 0
    assert "OK: 0 errors, 0 warnings" in capsys.readouterr().out


def test_cli_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = build(tmp_path / "ds")
    assert run_cli(["check", str(root), "--quiet", "--workers", "2"]) == 1
    assert "FAILED" in capsys.readouterr().out
    assert run_cli(["check", str(root), "--json"]) == 1
    data = json.loads(capsys.readouterr().out)
    kinds = data["splits"][0]["kinds"]
    assert kinds["missing_image"] == {"level": "error", "count": 1, "files": ["missing.jpg"]}

    # warnings only: exit 0, or 1 with --strict
    warn = tmp_path / "warn"
    build(warn, bad=False)
    cv2.imwrite(str(warn / "images" / "good.png"), np.full((H, W), 5, np.uint8))
    assert run_cli(["check", str(warn), "--quiet"]) == 0
    assert run_cli(["check", str(warn), "--quiet", "--strict"]) == 1


def test_yaml_input_with_names_mismatch(tmp_path: Path) -> None:
    root = build(tmp_path / "ds", bad=False)
    cfg = tmp_path / "data.yaml"
    cfg.write_text(
        "path: ds\ntrain: {images: images, annotations: annotations.json}\n"
        "val: {images: images, annotations: annotations.json}\nnames: [dog]\n"
    )
    report = check_dataset(cfg, progress=False)
    assert [s.name for s in report.splits] == ["train", "val"]
    assert report.kinds("val")["names_mismatch"] == 1 and report.errors == 2
    assert "dog" in report.files("names_mismatch")[0]
    report = check_dataset(cfg, split="val", progress=False)
    assert [s.name for s in report.splits] == ["val"]
    assert root.is_dir()
