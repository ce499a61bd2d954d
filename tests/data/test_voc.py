"""VOC XML to COCO json conversion, and loading the result as box instances."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.cli import data_coco
from slimseg.data.coco import CocoDataset
from slimseg.data.voc import voc_to_coco
from slimseg.errors import SlimsegError


def obj(name: str, box: tuple[int, int, int, int], difficult: int = 0) -> str:
    x0, y0, x1, y1 = box
    return (
        f"<object><name>{name}</name><pose>Left</pose><truncated>1</truncated>"
        f"<difficult>{difficult}</difficult><bndbox><xmin>{x0}</xmin><ymin>{y0}</ymin>"
        f"<xmax>{x1}</xmax><ymax>{y1}</ymax></bndbox></object>"
    )


def make_voc(root: Path) -> Path:
    """VOCdevkit/VOC2007 with 000001 (2 persons, 1 difficult person, a dog) and 000002 (car)."""
    devkit = root / "VOCdevkit"
    year = devkit / "VOC2007"
    for sub in ("Annotations", "JPEGImages", "ImageSets/Main"):
        (year / sub).mkdir(parents=True)
    xmls = {
        "000001": [
            obj("person", (1, 1, 20, 30)),
            obj("dog", (30, 10, 50, 40)),
            obj("person", (41, 5, 64, 48), difficult=1),
            obj("person", (10, 20, 15, 45)),
        ],
        "000002": [obj("car", (5, 5, 40, 30))],
    }
    for name, objects in xmls.items():
        (year / "Annotations" / f"{name}.xml").write_text(
            f"<annotation><folder>VOC2007</folder><filename>{name}.jpg</filename>"
            "<size><width>64</width><height>48</height><depth>3</depth></size>"
            f"<segmented>0</segmented>{''.join(objects)}</annotation>"
        )
        cv2.imwrite(str(year / "JPEGImages" / f"{name}.jpg"), np.zeros((48, 64, 3), np.uint8))
    (year / "ImageSets" / "Main" / "trainval.txt").write_text("000001\n000002\n")
    return devkit


def test_person_only_conversion(tmp_path: Path) -> None:
    devkit = make_voc(tmp_path)
    data, stats = voc_to_coco(devkit, ["2007/trainval"], classes=["person"])
    assert data["categories"] == [{"id": 1, "name": "person", "supercategory": "voc"}]
    assert [im["file_name"] for im in data["images"]] == ["VOC2007/JPEGImages/000001.jpg"]
    assert data["images"][0] == {
        "id": 1,
        "file_name": "VOC2007/JPEGImages/000001.jpg",
        "width": 64,
        "height": 48,
        "voc_id": "2007/000001",
    }
    anns = data["annotations"]
    assert [a["bbox"] for a in anns] == [[0, 0, 20, 30], [40, 4, 24, 44], [9, 19, 6, 26]]
    assert [a["iscrowd"] for a in anns] == [0, 1, 0]
    assert [a["difficult"] for a in anns] == [0, 1, 0]
    assert all("segmentation" not in a for a in anns)
    assert [a["id"] for a in anns] == [1, 2, 3] and anns[0]["area"] == 600
    assert stats.images_in == 2 and stats.images_out == 1 and stats.other_class == 2
    assert stats.rows() == [[1, "person", 3, 1]]


def test_all_classes_modes_and_loading(tmp_path: Path) -> None:
    devkit = make_voc(tmp_path)
    data, _ = voc_to_coco(tmp_path, ["VOC2007/trainval"], difficult="drop")  # finds VOCdevkit
    assert len(data["categories"]) == 20 and len(data["images"]) == 2
    assert [(a["image_id"], a["category_id"]) for a in data["annotations"]] == [
        (1, 15),
        (1, 12),
        (1, 15),
        (2, 7),
    ]
    data, _ = voc_to_coco(devkit, ["2007/trainval"], ["person"], "train", keep_unlabeled=True)
    assert len(data["images"]) == 2 and [a["iscrowd"] for a in data["annotations"]] == [0, 0, 0]

    out = tmp_path / "voc.json"
    parser = argparse.ArgumentParser()
    data_coco.add_parsers(parser.add_subparsers(dest="action", required=True))
    args = parser.parse_args(
        ["voc2coco", "--voc-root", str(devkit), "--sets", "2007/trainval", "--out", str(out)]
        + ["--classes", "person"]
    )
    assert args.run(args) == 0
    ds = CocoDataset(devkit, out)
    s = ds[0]
    assert ds.names == ("person",) and s.classes.tolist() == [0, 0]
    assert s.meta["box_masks"].tolist() == [True, True]
    assert s.masks.reshape(2, -1).sum(1).tolist() == [600, 156]
    assert s.meta["crowd_boxes"].tolist() == [[40, 4, 64, 48]]  # difficult: ignore region


def test_errors(tmp_path: Path) -> None:
    devkit = make_voc(tmp_path)
    with pytest.raises(SlimsegError, match="unknown or repeated"):
        voc_to_coco(devkit, ["2007/trainval"], classes=["human"])
    with pytest.raises(SlimsegError, match=r"test\.txt not found"):
        voc_to_coco(devkit, ["2007/test"])
    with pytest.raises(SlimsegError, match="expected YEAR/SET"):
        voc_to_coco(devkit, ["trainval"])
    (devkit / "VOC2007" / "Annotations" / "000002.xml").unlink()
    with pytest.raises(SlimsegError, match=r"000002\.xml: annotation file not found"):
        voc_to_coco(devkit, ["2007/trainval"])
