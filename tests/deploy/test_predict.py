"""Predictor (onnxruntime and torch backends) and the ``slimseg predict`` command."""

from __future__ import annotations

import argparse
import json
import warnings

import cv2
import numpy as np
import onnx
import pytest
import torch
from conftest import batchnorm_from, open_class_bias

import slimseg
from slimseg.cli import predict as predict_cli
from slimseg.data.frame_files import IMAGE_SUFFIXES, open_source
from slimseg.deploy.metadata import build_metadata, to_metadata_props
from slimseg.deploy.predictor import Predictor, combined_mask
from slimseg.detections import Prediction
from slimseg.errors import SlimsegError
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.ops.letterbox import letterbox_image, letterbox_params
from slimseg.utils.outputs import MANIFEST

NAMES = ["person", "chair", "car"]
MOBILITY = [1.0, 0.1, 0.8]
IMGSZ = 128


def _scene(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Float ``[3, h, w]`` in [0, 1]: a gradient with a few flat discs."""
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    img = np.stack([xx / w, yy / h, np.full_like(xx, 0.5)])
    for _ in range(6):
        cx, cy, r = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(8, min(h, w) / 3)
        img[:, (xx - cx) ** 2 + (yy - cy) ** 2 < r**2] = rng.random(3, dtype=np.float32)[:, None]
    return img


def _frame(seed: int, h: int = 100, w: int = 150) -> np.ndarray:
    """A non-square RGB uint8 test frame."""
    return (_scene(np.random.default_rng(seed), h, w).transpose(1, 2, 0) * 255).astype(np.uint8)


def _export(model: torch.nn.Module, path, metadata: bool = True) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            model,
            torch.zeros(1, 3, IMGSZ, IMGSZ),
            str(path),
            input_names=["images"],
            output_names=["output0", "output1"],
            opset_version=18,
            dynamo=False,
        )
    if metadata:
        proto = onnx.load(str(path))
        meta = build_metadata(model, NAMES, MOBILITY, (IMGSZ, IMGSZ))
        for key, value in to_metadata_props(meta).items():
            entry = proto.metadata_props.add()
            entry.key, entry.value = key, value
        onnx.save(proto, str(path))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A tiny yolov8n-seg with BatchNorm statistics taken from one batch of scenes (random
    init alone gives near-constant activations: equal scores, empty masks) and class bias 0,
    fused, saved as
    ``.pt`` and exported to ONNX with and without metadata."""
    root = tmp_path_factory.mktemp("predict")
    torch.manual_seed(0)
    model = slimseg.build_model("yolov8n-seg", num_classes=len(NAMES))
    rng = np.random.default_rng(0)
    batch = torch.from_numpy(np.stack([_scene(rng, IMGSZ, IMGSZ) for _ in range(4)]))
    fused = open_class_bias(batchnorm_from(model, batch)).fuse()
    info = WeightsInfo(fused.spec, NAMES, MOBILITY, train_config={"imgsz": IMGSZ})
    paths = {"pt": save_weights(root / "model.pt", fused, info)}
    paths["onnx"] = root / "model.onnx"
    paths["bare"] = root / "bare.onnx"
    _export(fused, paths["onnx"])
    _export(fused, paths["bare"], metadata=False)
    return paths


@pytest.fixture(scope="module")
def predictors(files):
    return (
        Predictor.from_path(files["onnx"], threads=1),
        Predictor.from_path(files["pt"], threads=1),
    )


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return 1.0 if union == 0 else float(np.logical_and(a, b).sum() / union)


@pytest.mark.parametrize("shape", [(100, 150), (150, 100)])
def test_backends_agree(predictors, shape):
    onnx_p, torch_p = predictors
    image = _frame(1, *shape)
    a = onnx_p.predict(image, conf=0.25, max_det=10)
    b = torch_p.predict(image, conf=0.25, max_det=10)
    assert len(a) == len(b) > 0
    np.testing.assert_array_equal(a.classes, b.classes)
    np.testing.assert_allclose(a.boxes, b.boxes, atol=1.0)
    np.testing.assert_allclose(a.scores, b.scores, atol=1e-3)
    assert a.masks.shape == b.masks.shape == (len(a), *shape)
    assert a.masks.dtype == bool and a.masks.any()
    assert min(_iou(ma, mb) for ma, mb in zip(a.masks, b.masks, strict=True)) > 0.98


def test_prediction_fields(predictors):
    onnx_p, torch_p = predictors
    for p in predictors:
        assert p.imgsz == (IMGSZ, IMGSZ) and p.names == NAMES and p.mobility == MOBILITY
        assert (p.family, p.task, p.precision) == ("yolov8", "segment", "fp32")
    assert (onnx_p.backend, torch_p.backend) == ("onnxruntime", "torch")
    pred = onnx_p.predict(_frame(2), conf=0.25, max_det=5)
    assert 0 < len(pred) <= 5 and pred.image_hw == (100, 150)
    assert pred.boxes.dtype == np.float32 and pred.boxes.shape == (len(pred), 4)
    assert (pred.boxes[:, [0, 2]] <= 150).all() and (pred.boxes[:, [1, 3]] <= 100).all()
    assert np.all(np.diff(pred.scores) <= 0) and (pred.scores > 0.25).all()
    assert pred.names == [NAMES[c] for c in pred.classes]
    assert pred.mobility == [MOBILITY[c] for c in pred.classes]
    assert set(pred.timings) == {"preprocess", "inference", "postprocess"}
    det = pred.detections()[0]
    assert set(det) == {"box", "class", "name", "score", "mobility"}
    json.dumps(pred.detections())


def test_preprocess_is_the_shared_letterbox(predictors):
    image = _frame(3)
    x, meta = predictors[0].preprocess(image)
    p = letterbox_params(100, 150, IMGSZ, IMGSZ)
    expected = letterbox_image(image, p).transpose(2, 0, 1)[None].astype(np.float32) / 255
    assert x.dtype == np.float32 and x.shape == (1, 3, IMGSZ, IMGSZ)
    np.testing.assert_array_equal(x, expected)
    assert meta["letterbox"] == p and meta["orig_shape"] == (100, 150)
    with pytest.raises(ValueError, match="RGB uint8"):
        predictors[0].predict(image[..., 0])


def test_predict_batch_matches_predict(predictors):
    images = [_frame(4), _frame(5, 90, 60)]
    for p in predictors:  # onnx: static batch 1, run one by one; torch: one forward
        batch = p.predict_batch(images, conf=0.25, max_det=5)
        for image, got in zip(images, batch, strict=True):
            single = p.predict(image, conf=0.25, max_det=5)
            assert len(got) == len(single) and got.image_hw == image.shape[:2]
            np.testing.assert_allclose(got.boxes, single.boxes, atol=1e-3)


def test_fp16_onnx(files, predictors, tmp_path):
    from onnxruntime.transformers.float16 import convert_float_to_float16

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        half = convert_float_to_float16(onnx.load(str(files["onnx"])), keep_io_types=False)
    for entry in half.metadata_props:
        if entry.key == "precision":
            entry.value = json.dumps("fp16")
    onnx.save(half, str(tmp_path / "half.onnx"))
    p16 = Predictor.from_path(tmp_path / "half.onnx", threads=1)
    assert p16.precision == "fp16" and p16.preprocess(_frame(1))[0].dtype == np.float16
    a = p16.predict(_frame(1), conf=0.25, max_det=10)
    b = predictors[1].predict(_frame(1), conf=0.25, max_det=10)
    assert len(a) == len(b) and a.boxes.dtype == np.float32 and a.masks.shape[1:] == (100, 150)


def test_combined_mask(predictors):
    pred = predictors[0].predict(_frame(1), conf=0.25, max_det=10)
    full = combined_mask(pred)
    assert full.dtype == np.uint8 and full.shape == (100, 150)
    np.testing.assert_array_equal(full == 255, pred.masks.any(axis=0))
    cls = int(pred.classes[0])
    by_id = combined_mask(pred, classes=[cls])
    np.testing.assert_array_equal(by_id, combined_mask(pred, classes=[NAMES[cls]]))
    np.testing.assert_array_equal(by_id == 255, pred.masks[pred.classes == cls].any(axis=0))
    assert not combined_mask(pred, classes=[]).any()
    boxes_only = Prediction(
        boxes=np.array([[10.0, 20.0, 30.5, 40.0]], np.float32),
        scores=np.ones(1, np.float32),
        classes=np.zeros(1, np.int64),
        names=["person"],
        mobility=[1.0],
        masks=None,
        image_hw=(50, 60),
    )
    filled = combined_mask(boxes_only)
    # pixel centres in the box: columns 10..29 (x = 30 has its centre on x2), rows 20..39
    assert filled.sum() == 255 * 20 * 20 and filled[20:40, 10:30].all()


def test_load_errors(files, tmp_path):
    with pytest.raises(SlimsegError, match="not exported by slimseg export"):
        Predictor.from_path(files["bare"])
    with pytest.raises(SlimsegError, match="not found"):
        Predictor.from_path(tmp_path / "missing.onnx")
    with pytest.raises(SlimsegError, match="torch backend"):
        Predictor.from_path(files["onnx"], backend="torch")
    with pytest.raises(SlimsegError, match="onnxruntime backend"):
        Predictor.from_path(files["pt"], backend="onnxruntime")
    with pytest.raises(SlimsegError, match="static 128x128"):
        Predictor.from_path(files["onnx"], imgsz=160)
    with pytest.raises(SlimsegError, match="multiples of 32"):
        Predictor.from_path(files["pt"], imgsz=100)
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(SlimsegError, match="onnxruntime cannot load"):
        Predictor.from_path(junk)


def _cli(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    predict_cli.add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["predict", *argv])


def _write_images(folder, n: int = 2) -> None:
    folder.mkdir()
    for i in range(n):
        cv2.imwrite(str(folder / f"img{i}.png"), cv2.cvtColor(_frame(i), cv2.COLOR_RGB2BGR))


def test_cli_folder(files, tmp_path, capsys):
    src, out = tmp_path / "images", tmp_path / "out"
    _write_images(src)
    args = _cli("--model", str(files["onnx"]), "--source", str(src), "--out", str(out))
    args.max_det, args.threads = 5, 1
    assert predict_cli.run(args) == 0
    assert "images/s" in capsys.readouterr().out
    names = sorted(p.name for p in out.iterdir())
    expected = [f"img{i}{s}" for i in range(2) for s in (".json", "_mask.png", "_overlay.png")]
    assert names == [MANIFEST, *expected]  # the manifest: slimseg wrote every file
    for i in range(2):
        record = json.loads((out / f"img{i}.json").read_text())
        assert set(record) == {"image", "size", "detections", "timings_ms"}
        assert record["image"] == str(src / f"img{i}.png") and record["size"] == [100, 150]
        assert set(record["timings_ms"]) == {"preprocess", "inference", "postprocess"}
        assert 0 < len(record["detections"]) <= 5
        for det in record["detections"]:
            assert set(det) == {"box", "class", "name", "score", "mobility"}
            assert det["name"] == NAMES[det["class"]] and det["score"] > 0.25
        mask = cv2.imread(str(out / f"img{i}_mask.png"), cv2.IMREAD_UNCHANGED)
        assert mask.shape == (100, 150) and mask.dtype == np.uint8
        assert set(np.unique(mask)) <= {0, 255} and mask.any()
        overlay = cv2.imread(str(out / f"img{i}_overlay.png"))
        assert overlay.shape == (100, 150, 3)
        assert not np.array_equal(overlay, cv2.cvtColor(_frame(i), cv2.COLOR_RGB2BGR))


def test_cli_skips_unreadable(files, tmp_path, capsys):
    src, out = tmp_path / "images", tmp_path / "out"
    _write_images(src)
    (src / "broken.jpg").write_bytes(b"\xff\xd8 definitely not a jpeg")
    args = _cli("--model", str(files["pt"]), "--source", str(src), "--out", str(out))
    args.max_det = 3
    assert predict_cli.run(args) == 1
    assert "skipped 1 unreadable file(s)" in capsys.readouterr().err
    assert sorted(p.name for p in out.glob("[!.]*.json")) == ["img0.json", "img1.json"]
    assert list(out.glob(".*")) == [out / MANIFEST]  # no temporary files left behind


def test_duplicate_stems_keep_both(tmp_path):
    for suffix in (".png", ".jpg"):
        cv2.imwrite(str(tmp_path / f"a{suffix}"), _frame(0))
    frames, total, is_video = predict_cli.open_source(tmp_path)
    assert (total, is_video) == (2, False)
    assert [stem for stem, _, _ in frames] == ["a_jpg", "a_png"]


def test_cli_video(files, tmp_path):
    video, out = tmp_path / "clip.avi", tmp_path / "out"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 5, (150, 100))
    if not writer.isOpened():
        pytest.skip("OpenCV has no MJPG writer here")
    for i in range(2):
        writer.write(cv2.cvtColor(_frame(i), cv2.COLOR_RGB2BGR))
    writer.release()
    args = _cli("--model", str(files["onnx"]), "--source", str(video), "--out", str(out))
    args.max_det = 3
    assert predict_cli.run(args) == 0
    jsons = sorted(p.name for p in out.glob("[!.]*.json"))
    assert jsons == ["frame_000000.json", "frame_000001.json"]
    record = json.loads((out / "frame_000001.json").read_text())
    assert record["frame"] == 1 and record["size"] == [100, 150]


def test_every_image_suffix_is_read(tmp_path) -> None:
    """A folder of frames in each suffix ``predict`` (and the INT8 calibration) lists: every one
    decodes to the RGB written, in name order."""
    rgb = np.zeros((8, 12, 3), np.uint8)
    rgb[:, :6] = (200, 40, 10)
    lossless = [cv2.IMWRITE_JPEG_QUALITY, 100, cv2.IMWRITE_WEBP_QUALITY, 101]
    for k, suffix in enumerate(IMAGE_SUFFIXES):
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        assert cv2.imwrite(str(tmp_path / f"f{k}{suffix}"), bgr, lossless), suffix
    frames, count, video = open_source(tmp_path)
    got = list(frames)
    assert count == len(IMAGE_SUFFIXES) and not video
    assert [stem for stem, _, _ in got] == [f"f{k}" for k in range(len(IMAGE_SUFFIXES))]
    for (_, path, image), suffix in zip(got, IMAGE_SUFFIXES, strict=True):
        assert image is not None and image.shape == rgb.shape, path
        tol = 40 if suffix in (".jpg", ".jpeg") else 0  # lossy at the red/black edge
        assert np.abs(image.astype(int) - rgb).max() <= tol, suffix


def test_cli_bad_sources(files, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no images here")
    for source, match in (
        (empty, "no .png/.jpg/.jpeg/.bmp/.tif/.tiff/.webp images"),
        (tmp_path / "missing", "no such file or folder"),
        (empty / "notes.txt", "nor a video"),
    ):
        args = _cli("--model", str(files["onnx"]), "--source", str(source))
        with pytest.raises(SlimsegError, match=match):
            predict_cli.run(args)
