"""CocoDataset: mask decoding, loading rules, category mapping; dataset config loading."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from pycocotools import mask as mask_utils

from slimseg.data.coco import CocoDataset
from slimseg.data.config import load_data_config
from slimseg.errors import SlimsegError

H, W = 40, 60


def rect(x0: float, y0: float, x1: float, y1: float) -> list[float]:
    """Polygon of an axis-aligned rectangle (pycocotools fills [x0, x1) x [y0, y1))."""
    return [x0, y0, x1, y0, x1, y1, x0, y1]


def block(r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    m = np.zeros((H, W), np.uint8)
    m[r0:r1, c0:c1] = 1
    return m


def uncompressed_rle(mask: np.ndarray) -> dict:
    """Column-major run lengths starting with a run of zeros (our own encoder)."""
    flat = mask.flatten(order="F")
    counts, current, run = [], 0, 0
    for v in flat:
        if v == current:
            run += 1
        else:
            counts.append(run)
            current, run = int(v), 1
    counts.append(run)
    return {"size": [int(mask.shape[0]), int(mask.shape[1])], "counts": counts}


def compressed_rle(mask: np.ndarray) -> dict:
    rle = mask_utils.encode(np.asfortranarray(mask))
    return {"size": [int(s) for s in rle["size"]], "counts": rle["counts"].decode("ascii")}


def ann(i: int, cat: int, segm: object = None, bbox: list[float] | None = None, **kw) -> dict:
    a = {"id": i, "image_id": 1, "category_id": cat, "iscrowd": 0, **kw}
    if segm is not None:
        a["segmentation"] = segm
    if bbox is not None:
        a["bbox"] = bbox
    return a


def write_dataset(tmp: Path, anns: list[dict], image: np.ndarray | None = None) -> Path:
    images = tmp / "images"
    images.mkdir(exist_ok=True)
    if image is None:
        image = np.zeros((H, W, 3), np.uint8)
        image[:, :, 0] = 255  # blue in BGR
    cv2.imwrite(str(images / "a.png"), image)
    data = {
        "images": [{"id": 1, "file_name": "a.png", "width": W, "height": H}],
        "annotations": anns,
        "categories": [
            {"id": 5, "name": "dog"},
            {"id": 2, "name": "person"},
            {"id": 9, "name": "chair"},
        ],
    }
    path = tmp / "ann.json"
    path.write_text(json.dumps(data))
    return path


def full_annotations() -> list[dict]:
    crowd = compressed_rle(block(30, 40, 40, 60))
    return [
        ann(1, 2, [rect(10, 10, 30, 20)], [10, 10, 20, 10]),  # 200 px
        ann(2, 5, [rect(0, 0, 10, 10), rect(40, 20, 50, 30)], [0, 0, 50, 30]),  # 2 x 100
        ann(3, 9, uncompressed_rle(block(30, 35, 5, 15)), [5, 30, 10, 5]),  # 50
        ann(4, 2, compressed_rle(block(0, 5, 50, 60)), [50, 0, 10, 5]),  # 50
        ann(5, 2, crowd, [40, 30, 20, 10], iscrowd=1),
        ann(6, 5, None, [5, 22, 10, 8]),  # box only: 80 px
        ann(7, 2, [[1, 1, 5, 5]], [1, 1, 4, 4]),  # 2 points
        ann(8, 2, [[0, 0, 5, 5, 10, 10]], [0, 0, 10, 10]),  # collinear: zero area
        ann(9, 9, [rect(50, 30, 60, 40)], [50, 30, 20, 20]),  # box leaves the image
        ann(10, 99, [rect(0, 0, 5, 5)], [0, 0, 5, 5]),  # unknown category
    ]


def test_masks_boxes_classes_and_report(tmp_path: Path) -> None:
    ds = CocoDataset(tmp_path / "images", write_dataset(tmp_path, full_annotations()))
    assert ds.names == ("person", "dog", "chair") and ds.cat_ids == (2, 5, 9)
    assert len(ds) == 1
    s = ds[0]
    assert s.image.dtype == np.uint8 and s.image.shape == (H, W, 3)
    assert s.image[0, 0].tolist() == [0, 0, 255]  # BGR file -> RGB sample
    assert s.meta["ann_ids"].tolist() == [1, 2, 3, 4, 6, 9]
    assert s.classes.tolist() == [0, 1, 2, 0, 1, 2] and s.classes.dtype == np.int64
    assert s.masks.dtype == np.uint8 and s.masks.shape == (6, H, W)
    assert s.masks.reshape(6, -1).sum(1).tolist() == [200, 200, 50, 50, 80, 100]
    assert np.array_equal(s.masks[0], block(10, 20, 10, 30))
    assert np.array_equal(s.masks[1], block(0, 10, 0, 10) | block(20, 30, 40, 50))
    assert np.array_equal(s.masks[2], block(30, 35, 5, 15))
    assert np.array_equal(s.masks[3], block(0, 5, 50, 60))
    assert np.array_equal(s.masks[4], block(22, 30, 5, 15))
    assert s.meta["box_masks"].tolist() == [False, False, False, False, True, False]
    assert s.boxes.dtype == np.float32
    assert s.boxes[5].tolist() == [50, 30, 60, 40]  # clipped
    assert s.boxes[0].tolist() == [10, 10, 30, 20]
    # the crowd region is not a target, but is available
    assert s.meta["crowd_masks"].shape == (1, H, W)
    assert int(s.meta["crowd_masks"].sum()) == 200
    assert s.meta["crowd_classes"].tolist() == [0]
    r = ds.report
    assert r["polygon_few_points"] == 1 and r["polygon_zero_area"] == 1
    assert r["box_clipped"] == 1 and r["unknown_category"] == 1 and r["crowd"] == 1
    assert r["box_only"] == 1
    assert r.examples["unknown_category"] == ["a.png (ann 10, category 99)"]
    assert "unknown_category" in r.summary()


def test_names_order_mapping(tmp_path: Path) -> None:
    path = write_dataset(tmp_path, full_annotations())
    ds = CocoDataset(tmp_path / "images", path, names=["chair", "person"])
    assert ds.names == ("chair", "person") and ds.cat_ids == (9, 2)
    s = ds[0]
    assert s.meta["ann_ids"].tolist() == [1, 3, 4, 9]
    assert s.classes.tolist() == [1, 0, 1, 0]
    assert ds.report["category_not_selected"] == 2  # the dog annotations
    with pytest.raises(SlimsegError, match="horse"):
        CocoDataset(tmp_path / "images", path, names=["person", "horse"])


@pytest.mark.parametrize(
    ("image", "kind"),
    [
        (np.full((H, W), 77, np.uint8), "grayscale_image"),
        (np.full((H, W, 4), 77, np.uint8), "rgba_image"),
        (np.full((H, W, 3), 77 * 257, np.uint16), "16bit_image"),
    ],
)
def test_image_conversions(tmp_path: Path, image: np.ndarray, kind: str) -> None:
    path = write_dataset(tmp_path, [ann(1, 2, [rect(0, 0, 10, 10)])], image)
    ds = CocoDataset(tmp_path / "images", path)
    s = ds[0]
    assert s.image.shape == (H, W, 3) and s.image.dtype == np.uint8
    assert int(s.image[5, 5, 0]) == 77
    assert s.boxes.tolist() == [[0, 0, 10, 10]]  # derived from the polygon
    ds[0]
    assert ds.report[kind] == 1  # counted once per image, not per load


def test_unreadable_and_mismatched_images_raise(tmp_path: Path) -> None:
    path = write_dataset(tmp_path, [ann(1, 2, [rect(0, 0, 10, 10)])])
    ds = CocoDataset(tmp_path / "images", path)
    cv2.imwrite(str(tmp_path / "images" / "a.png"), np.zeros((H + 1, W, 3), np.uint8))
    with pytest.raises(SlimsegError, match=r"a\.png.*60x41.*60x40"):
        ds[0]
    (tmp_path / "images" / "a.png").write_bytes(b"not an image")
    with pytest.raises(SlimsegError, match=r"a\.png: corrupt"):
        ds[0]
    (tmp_path / "images" / "a.png").unlink()
    with pytest.raises(SlimsegError, match=r"a\.png: image file not found"):
        ds[0]
    with pytest.raises(IndexError):
        ds[1]


def test_empty_image_and_depth(tmp_path: Path) -> None:
    path = write_dataset(tmp_path, [])
    depth = tmp_path / "depth"
    depth.mkdir()
    cv2.imwrite(str(depth / "a.png"), np.full((H, W), 5000, np.uint16))
    s = CocoDataset(tmp_path / "images", path, depth_dir=depth)[0]
    assert s.num_instances == 0 and s.masks.shape == (0, H, W) and s.boxes.shape == (0, 4)
    assert s.depth is not None and s.depth.dtype == np.uint16 and int(s.depth[0, 0]) == 5000


# ---------------------------------------------------------------------------- data config


def write_yaml(tmp: Path, text: str) -> Path:
    p = tmp / "data.yaml"
    p.write_text(text)
    return p


def test_data_config_defaults_and_paths(tmp_path: Path) -> None:
    write_dataset(tmp_path, [])
    cfg = load_data_config(
        write_yaml(
            tmp_path,
            "train: {images: images, annotations: ann.json}\nval: {images: images, annotations: "
            "ann.json}\n",
        )
    )
    assert cfg.root == tmp_path.resolve()
    assert cfg.train is not None and cfg.train.images == (tmp_path / "images").resolve()
    assert cfg.names == ("person", "dog", "chair")  # json sorted by id
    assert cfg.mobility == () and cfg.num_classes == 3
    assert cfg.split("val").annotations == (tmp_path / "ann.json").resolve()


def test_data_config_path_names_mobility(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    root.mkdir()
    write_dataset(root, [])
    yaml_dir = tmp_path / "cfg"
    yaml_dir.mkdir()
    body = "path: ../ds\nval: {images: images, annotations: ann.json}\nnames: [chair, person]\n"
    cfg = load_data_config(write_yaml(yaml_dir, body + "mobility: {person: 1.0, chair: 0.25}\n"))
    assert cfg.root == root.resolve() and cfg.train is None
    assert cfg.names == ("chair", "person") and cfg.mobility == (0.25, 1.0)
    with pytest.raises(SlimsegError, match="no 'train' split"):
        cfg.split("train")
    cfg = load_data_config(write_yaml(yaml_dir, body + "mobility: [0.25, 1]\n"))
    assert cfg.mobility == (0.25, 1.0)


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ("epochs: 3\n", r"data\.yaml: unknown keys \['epochs'\]"),
        ("names: [person]\nmobility: [1.0, 0.5]\n", r"'mobility': has 2 values but .* 1 names"),
        ("mobility: {person: 2.0, dog: 1, chair: 0}\n", r"'mobility\.person'"),
        ("mobility: {person: 1.0}\n", r"missing: \['dog', 'chair'\]"),
        ("names: [a, a]\n", r"'names': duplicate"),
        ("sequence: [seq]\n", r"unknown keys \['sequence'\]"),  # a typo stays an error
        ("sequences: seq\n", r"'sequences': expected a non-empty list"),
        ("sequences: [nope]\n", r"'sequences\[0\]': folder .*nope not found"),
        ("sequences: [images]\n", r"'sequences\[0\]': .*images is not a TUM-layout .*rgb\.txt"),
    ],
)
def test_data_config_errors(tmp_path: Path, extra: str, match: str) -> None:
    write_dataset(tmp_path, [])
    with pytest.raises(SlimsegError, match=match):
        load_data_config(
            write_yaml(tmp_path, "val: {images: images, annotations: ann.json}\n" + extra)
        )


def test_data_config_sequences(tmp_path: Path) -> None:
    """``sequences`` (what 'slimseg data synth --sequences' writes): TUM folders by name; a
    yaml with only sequences loads, needs names, and has no split to train on."""
    for name in ("a", "b"):
        (tmp_path / "seqs" / name).mkdir(parents=True)
        for f in ("rgb.txt", "depth.txt"):
            (tmp_path / "seqs" / name / f).write_text("# empty\n")
    cfg = load_data_config(write_yaml(tmp_path, "sequences: [seqs/a, seqs/b]\nnames: [person]\n"))
    assert cfg.sequences == {n: (tmp_path / "seqs" / n).resolve() for n in ("a", "b")}
    assert cfg.train is None and cfg.val is None and cfg.mobility == ()
    with pytest.raises(SlimsegError, match=r"data\.yaml: no 'train' split \(it lists only"):
        cfg.split("train")
    cfg = load_data_config(write_yaml(tmp_path, "sequences: {x: seqs/b}\nnames: [p]\n"))
    assert cfg.sequences == {"x": (tmp_path / "seqs" / "b").resolve()}
    with pytest.raises(SlimsegError, match=r"'names': required when there is no train/val"):
        load_data_config(write_yaml(tmp_path, "sequences: [seqs/a]\n"))
    with pytest.raises(SlimsegError, match=r"'sequences\[1\]': a second sequence named 'a'"):
        load_data_config(write_yaml(tmp_path, "sequences: [seqs/a, ./seqs/a]\nnames: [p]\n"))


def test_data_config_missing_files(tmp_path: Path) -> None:
    write_dataset(tmp_path, [])
    with pytest.raises(SlimsegError, match=r"'val\.annotations': file .*nope\.json not found"):
        load_data_config(write_yaml(tmp_path, "val: {images: images, annotations: nope.json}\n"))
    with pytest.raises(SlimsegError, match=r"'train\.images': folder"):
        load_data_config(write_yaml(tmp_path, "train: {images: imgs, annotations: ann.json}\n"))
    with pytest.raises(SlimsegError, match=r"'val': unknown keys \['labels'\]"):
        load_data_config(
            write_yaml(tmp_path, "val: {images: images, annotations: ann.json, labels: x}\n")
        )


def test_dataset_from_config(tmp_path: Path) -> None:
    write_dataset(tmp_path, full_annotations())
    cfg = load_data_config(
        write_yaml(tmp_path, "val: {images: images, annotations: ann.json}\nnames: [dog]\n")
    )
    s = CocoDataset.from_config(cfg, "val")[0]
    assert s.classes.tolist() == [0, 0] and s.meta["ann_ids"].tolist() == [2, 6]


def test_malformed_annotations_are_dropped_and_reported(tmp_path: Path) -> None:
    wrong_size = uncompressed_rle(block(0, 5, 0, 5))
    wrong_size["size"] = [H + 1, W]
    anns = [
        ann(1, 2, rect(0, 0, 10, 10)),  # flat polygon (no outer list): accepted
        ann(2, 2, [[0, 0, "x", 0, 4, 4]]),  # non-numeric coordinate
        ann(3, 2, wrong_size),  # RLE of another size
        ann(4, 2, [[10.1, 10.1, 10.3, 10.1, 10.3, 10.3]]),  # no pixel after rasterising
        {"id": 5, "image_id": 77, "category_id": 2},  # image 77 does not exist
        ann(6, 2, None, [3, 3, 0, 5]),  # zero-width box
    ]
    ds = CocoDataset(tmp_path / "images", write_dataset(tmp_path, anns))
    s = ds[0]
    assert s.meta["ann_ids"].tolist() == [1] and int(s.masks.sum()) == 100
    r = ds.report
    assert r["bad_segmentation"] == 2 and r["orphan_annotation"] == 1
    assert r["box_outside"] == 1 and r["empty_mask"] == 1
    assert r.examples["empty_mask"] == ["a.png (ann 4)"]


def test_not_a_coco_json(tmp_path: Path) -> None:
    write_dataset(tmp_path, [])
    (tmp_path / "bad.json").write_text('{"images": []}')
    with pytest.raises(SlimsegError, match=r"bad\.json: 'annotations' must be a list"):
        CocoDataset(tmp_path / "images", tmp_path / "bad.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(SlimsegError, match=r"bad\.json: not a readable JSON file"):
        CocoDataset(tmp_path / "images", tmp_path / "bad.json")


def test_batched_mask_decode_equals_one_decode_per_instance() -> None:
    from slimseg.data.coco_index import Instance
    from slimseg.data.coco_rle import decode_instance_mask, decode_instance_masks

    h, w = 23, 31
    m = np.zeros((h, w, 2), np.uint8, order="F")
    m[2:9, 3:20, 0] = 1
    m[10:22, 0:5, 1] = 1
    rles = mask_utils.encode(m)
    insts = [
        Instance(ann_id=1, cls=0, box=(3.0, 2.0, 20.0, 9.0), segm=rles[0], crowd=False),
        Instance(
            ann_id=2, cls=1, box=(4.2, 5.0, 12.7, 19.1), segm=None, crowd=False
        ),  # box instance
        Instance(ann_id=3, cls=0, box=(0.0, 10.0, 5.0, 22.0), segm=rles[1], crowd=False),
    ]
    out = decode_instance_masks(insts, h, w)
    assert out.dtype == np.uint8 and out.shape == (3, h, w) and out.flags.c_contiguous
    for k, inst in enumerate(insts):
        np.testing.assert_array_equal(out[k], decode_instance_mask(inst, h, w))
    assert decode_instance_masks([], h, w).shape == (0, h, w)
