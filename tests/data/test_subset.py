"""COCO-20 subset builder, the classes file and the example data config."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest
import yaml

from slimseg.cli import data_coco
from slimseg.data.config import load_data_config
from slimseg.data.subset import build_subset, load_class_list
from slimseg.errors import SlimsegError
from slimseg.utils.shipped import shipped_dir

COCO20 = shipped_dir("data") / "coco20.yaml"
PAPER_ORDER = [
    "person", "bicycle", "car", "motorcycle", "bird", "cat", "dog", "backpack", "umbrella",
    "handbag", "suitcase", "sports ball", "bottle", "chair", "tv", "laptop", "mouse",
    "keyboard", "cell phone", "refrigerator",
]  # fmt: skip
COCO_IDS = [1, 2, 3, 4, 16, 17, 18, 27, 28, 31, 33, 37, 44, 62, 72, 73, 74, 76, 77, 82]


def run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    data_coco.add_parsers(parser.add_subparsers(dest="action", required=True))
    args = parser.parse_args(argv)
    return args.run(args)


def coco_json() -> dict:
    """Images: 1 person+airplane+crowd person, 2 airplane, 3 crowd only, 4 dog+tv, 5 empty."""

    def a(i: int, img: int, cat: int, crowd: int = 0) -> dict:
        return {
            "id": i,
            "image_id": img,
            "category_id": cat,
            "bbox": [0, 0, 2, 2],
            "iscrowd": crowd,
        }

    anns = [(10, 1, 1), (11, 1, 5), (12, 1, 1, 1), (13, 2, 5)]
    anns += [(14, 3, 1, 1), (15, 4, 18), (16, 4, 72), (17, 4, 18)]
    others = [
        {"id": i, "name": n}
        for n, i in zip(PAPER_ORDER, COCO_IDS, strict=True)
        if i not in (1, 18, 72)
    ]
    return {
        "info": {"description": "tiny"},
        "licenses": [{"id": 1, "name": "x"}],
        "images": [
            {"id": i, "file_name": f"{i:012d}.jpg", "width": 8, "height": 8} for i in range(1, 6)
        ],
        "annotations": [a(*t) for t in anns],
        "categories": [
            {"id": 1, "name": "person", "supercategory": "person"},
            {"id": 5, "name": "airplane", "supercategory": "vehicle"},
            {"id": 18, "name": "dog", "supercategory": "animal"},
            {"id": 72, "name": "tv", "supercategory": "electronic"},
            *others,
        ],
    }


def test_coco20_classes_file() -> None:
    classes = load_class_list(COCO20)
    assert [c.name for c in classes] == PAPER_ORDER
    assert [c.coco_id for c in classes] == COCO_IDS
    mob = {c.name: c.mobility for c in classes}
    assert (mob["person"], mob["sports ball"], mob["keyboard"]) == (1.0, 0.75, 0.25)
    assert all(m * 4 == int(m * 4) and 0 <= m <= 1 for m in mob.values())


def test_subset_remaps_in_paper_order() -> None:
    out, stats = build_subset(coco_json(), load_class_list(COCO20), source="x.json")
    cats = out["categories"]
    assert [c["id"] for c in cats] == list(range(1, 21))
    assert [c["name"] for c in cats] == PAPER_ORDER
    assert [c["coco_id"] for c in cats] == COCO_IDS
    assert cats[0]["mobility"] == 1.0 and cats[0]["supercategory"] == "person"
    # images 2 (airplane only), 3 (crowd only) and 5 (empty) are dropped
    assert [im["id"] for im in out["images"]] == [1, 4]
    anns = {a["id"]: a for a in out["annotations"]}
    assert sorted(anns) == [10, 12, 15, 16, 17]  # crowd 12 kept, crowd 14 left with image 3
    assert anns[10]["category_id"] == 1 and anns[12]["iscrowd"] == 1
    assert anns[15]["category_id"] == 7 and anns[16]["category_id"] == 15
    assert out["licenses"] == [{"id": 1, "name": "x"}]
    assert out["info"]["slimseg_subset"]["source"] == "x.json"
    assert stats.instances[:7] == [1, 0, 0, 0, 0, 0, 2] and stats.crowd[0] == 1
    assert stats.images_per_class[6] == 1 and stats.images_out == 2 and not stats.warnings


def test_subset_keep_unlabeled_and_name_warning() -> None:
    data = coco_json()
    data["categories"][3]["name"] = "tvmonitor"
    out, stats = build_subset(data, load_class_list(COCO20), keep_unlabeled=True)
    assert [im["id"] for im in out["images"]] == [1, 2, 3, 4, 5]
    assert sorted(a["id"] for a in out["annotations"]) == [10, 12, 14, 15, 16, 17]
    assert out["categories"][14]["name"] == "tv"
    assert len(stats.warnings) == 1 and "tvmonitor" in stats.warnings[0]


def test_subset_falls_back_to_name(tmp_path: Path) -> None:
    data = coco_json()
    data["categories"][3]["id"] = 99
    for a in data["annotations"]:
        if a["category_id"] == 72:
            a["category_id"] = 99
    out, stats = build_subset(data, load_class_list(COCO20))
    assert out["categories"][14]["coco_id"] == 99 and "matched 'tv' by name" in stats.warnings[0]
    del data["categories"][3]
    with pytest.raises(SlimsegError, match="no category with id 72 or name 'tv'"):
        build_subset(data, load_class_list(COCO20))


def test_coco_subset_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "annotations" / "instances_train2017.json"
    src.parent.mkdir()
    src.write_text(json.dumps(coco_json()))
    images = tmp_path / "train2017"
    images.mkdir()
    out = tmp_path / "coco20"
    argv = ["coco-subset", "--ann", str(src), "--classes", str(COCO20), "--out", str(out)]
    assert run_cli([*argv, "--images", str(images)]) == 0
    text = capsys.readouterr().out
    assert "sports ball" in text and "kept 2/5 images" in text
    assert [p.name for p in out.iterdir()] == ["instances_train2017.json"]  # no temp left
    data = json.loads((out / "instances_train2017.json").read_text())
    assert data["info"]["slimseg_subset"]["images_dir"] == str(images.resolve())
    assert len(data["images"]) == 2
    assert run_cli([*argv, "--keep-unlabeled"]) == 0
    assert len(json.loads((out / "instances_train2017.json").read_text())["images"]) == 5
    with pytest.raises(SlimsegError, match="would overwrite"):
        run_cli(
            ["coco-subset", "--ann", str(src), "--classes", str(COCO20), "--out", str(src.parent)]
        )


def test_example_config_loads_subset(tmp_path: Path) -> None:
    raw = yaml.safe_load((shipped_dir("data") / "coco20-example.yaml").read_text())
    assert set(raw) == {"path", "train", "val", "names"} and raw["names"] == PAPER_ORDER
    raw["path"] = str(tmp_path)
    for split in ("train", "val"):
        (tmp_path / raw[split]["images"]).mkdir()
        out, _ = build_subset(coco_json(), load_class_list(COCO20))
        ann = tmp_path / raw[split]["annotations"]
        ann.parent.mkdir(exist_ok=True)
        ann.write_text(json.dumps(out))
    cfg_path = tmp_path / "data.yaml"
    cfg_path.write_text(yaml.safe_dump(raw))
    cfg = load_data_config(cfg_path)
    assert cfg.names == tuple(PAPER_ORDER)
    assert cfg.mobility == tuple(c.mobility for c in load_class_list(COCO20))
