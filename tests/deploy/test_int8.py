"""INT8 export for both targets (TensorRT: placement, symmetric Q/DQ; onnxruntime: uint8
activations over the whole body), the accuracy gate, bad input, and ``slimseg val`` / the
predictor on exported files. The dataset's labels are the FP32 model's own confident
detections, so the FP32 graph scores high and an INT8 graph that changes detections visibly
loses mAP."""

from __future__ import annotations

import copy
import json
import os
import re
import subprocess
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
import torch
from conftest import batchnorm_from, disc_scene, open_class_bias
from onnx import numpy_helper

import slimseg
from slimseg.cli.main import main
from slimseg.deploy.calibration import load_calibration_set
from slimseg.deploy.int8_placement import plan_placement
from slimseg.deploy.int8_quantize import check_onnxruntime, quantize_onnx
from slimseg.deploy.metadata import from_metadata_props
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.predictor import Predictor
from slimseg.detections import encode_rle
from slimseg.errors import SlimsegError
from slimseg.models.checkpoint import WeightsInfo, save_weights

NAMES = ["person", "chair", "car"]
IMGSZ = 96
FRAMES = 6


def _scene(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """RGB ``uint8 [h, w, 3]``: a gradient with a few flat discs."""
    return (disc_scene(rng, h, w, 6) * 255).astype(np.uint8)


@pytest.fixture(scope="module")
def setup(tmp_path_factory) -> dict[str, Path]:
    """A yolov8n-seg with BatchNorm statistics from real-looking frames (so it detects), its
    ``.pt`` and FP32 export, and a data YAML whose val labels are that model's detections."""
    root = tmp_path_factory.mktemp("int8")
    torch.manual_seed(0)
    model = slimseg.build_model("yolov8n-seg", num_classes=len(NAMES))
    rng = np.random.default_rng(0)
    frames = [_scene(rng, 80, IMGSZ) for _ in range(FRAMES)]
    # BatchNorm statistics of these frames (outputs that depend on the image)
    batch = np.stack([cv2.resize(f, (IMGSZ, IMGSZ)) for f in frames]).transpose(0, 3, 1, 2)
    open_class_bias(batchnorm_from(model, torch.from_numpy(batch).float() / 255))
    with torch.no_grad():
        # smaller box logits and mask terms (from when the FP32 gate had absolute limits; it
        # now scales with magnitude: tests/deploy/test_export_parity.py covers values of ~100)
        for conv in [b[-1] for b in model.detect.box] + [model.proto.cv3.conv]:
            conv.weight.mul_(0.01)
    model = model.eval()
    info = WeightsInfo(model.spec, NAMES, [1.0, 0.1, 0.8], train_config={"imgsz": IMGSZ})
    paths = {"pt": save_weights(root / "model.pt", model, info)}
    # The same function with one outlier activation channel: stem conv 0's channel 0 sits at
    # ~400 while the next conv ignores it (zero weights), so FP32 outputs are unchanged but a
    # per-tensor INT8 scale of that activation leaves the other channels ~1 step of 3.
    outlier = copy.deepcopy(model)
    with torch.no_grad():
        outlier.backbone.stem[0].bn.bias[0] = 400.0
        outlier.backbone.stem[1].conv.weight[:, 0] = 0.0
    paths["outlier"] = save_weights(root / "outlier.pt", outlier, info)
    paths["fp32"] = export_onnx(model, root / "fp32.onnx", (IMGSZ, IMGSZ), NAMES).path
    images = root / "val" / "images"
    images.mkdir(parents=True)
    predictor = Predictor.from_path(paths["fp32"], threads=1)
    records, anns = [], []
    for i, frame in enumerate(frames):
        name = f"f{i}.png"
        cv2.imwrite(str(images / name), frame[:, :, ::-1])
        records.append({"id": i + 1, "file_name": name, "height": 80, "width": IMGSZ})
        pred = predictor.predict(frame, conf=0.3, max_det=4)
        for box, cls, rle in zip(pred.boxes, pred.classes, encode_rle(pred.masks), strict=True):
            x1, y1, x2, y2 = (float(v) for v in box)
            anns.append(
                {
                    "id": len(anns) + 1,
                    "image_id": i + 1,
                    "category_id": int(cls) + 1,
                    "bbox": [x1, y1, x2 - x1, y2 - y1],
                    "segmentation": rle,
                    "area": float((x2 - x1) * (y2 - y1)),
                    "iscrowd": 0,
                }
            )
    assert len(anns) >= FRAMES, "the fixture model should detect something in every frame"
    cats = [{"id": k + 1, "name": n} for k, n in enumerate(NAMES)]
    (root / "val" / "annotations.json").write_text(
        json.dumps({"images": records, "annotations": anns, "categories": cats})
    )
    paths["data"] = root / "data.yaml"
    paths["data"].write_text(
        "path: .\nval: {images: val/images, annotations: val/annotations.json}\n"
        f"names: {json.dumps(NAMES)}\n"
    )
    paths["images"] = images
    return paths


def _export_int8(setup: dict[str, Path], out: Path, *extra: str, weights: str = "pt") -> int:
    argv = ["export", "--weights", str(setup[weights]), "--imgsz", str(IMGSZ), "--int8"]
    return main([*argv, "--quiet", "--out", str(out), *extra])


@pytest.mark.slow
def test_int8_export_placement_symmetric_and_metadata(setup, tmp_path: Path, capsys) -> None:
    out = tmp_path / "m-int8.onnx"
    code = _export_int8(setup, out, "--calib", str(setup["data"]), "--int8-max-drop", "100")
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "mAP50-95 FP32 -> INT8" in printed.out and "agreement with FP32" in printed.out
    proto = onnx.load(str(out))
    g = proto.graph
    inits = {t.name: numpy_helper.to_array(t) for t in g.initializer}
    # every zero point is 0 and int8 (TensorRT's rule); no int32 bias dequantization
    zps = [n.input[2] for n in g.node if n.op_type in ("QuantizeLinear", "DequantizeLinear")]
    assert zps and all(inits[z].dtype == np.int8 and not inits[z].any() for z in zps)
    assert not [t for t in inits.values() if t.dtype == np.int32]
    # Q/DQ exactly where the placement says: on both inputs (and the output) of the chosen
    # convs; the kept convs compute in floating point (no DQ on their inputs), and every Q
    # quantizes a chosen conv's output or an input of one
    plan = plan_placement(proto, "yolov8")
    producers = {o: n for n in g.node for o in n.output}
    consumers: dict[str, list] = {}
    for n in g.node:
        for i in n.input:
            consumers.setdefault(i, []).append(n)
    convs = {n.name: n for n in g.node if n.op_type in ("Conv", "ConvTranspose")}

    def op_of(tensor: str) -> str | None:
        return producers[tensor].op_type if tensor in producers else None

    for name in plan.quantize:
        assert [op_of(i) for i in convs[name].input[:2]] == ["DequantizeLinear"] * 2, name
        assert {c.op_type for c in consumers[convs[name].output[0]]} == {"QuantizeLinear"}
    for name, why in plan.keep.items():
        assert "DequantizeLinear" not in [op_of(i) for i in convs[name].input], (name, why)
    assert {"first conv", "predictor or DFL conv"} <= set(plan.keep.values())
    chosen = set(plan.quantize)
    for q in (n for n in g.node if n.op_type == "QuantizeLinear"):
        src = producers.get(q.input[0])
        feeds = {c.name for dq in consumers[q.output[0]] for c in consumers[dq.output[0]]}
        assert (src is not None and src.name in chosen) or feeds & chosen, q.name
    meta = from_metadata_props({p.key: p.value for p in proto.metadata_props})
    sidecar = json.loads(out.with_suffix(".json").read_text())
    assert meta == sidecar and meta["precision"] == "int8"
    assert meta["int8"]["calibration"]["images"] == FRAMES
    assert meta["int8"]["calibration"]["method"] == "minmax"
    assert set(meta["int8"]["map50_95"]["fp32"]) == {"box", "mask"}
    assert Predictor.from_path(out).precision == "int8"


@pytest.mark.slow
def test_gate_refuses_and_leaves_nothing(setup, tmp_path: Path, capsys) -> None:
    """An outlier activation channel (FP32 outputs untouched) wrecks per-tensor INT8: the
    gate measures the mAP drop, refuses the export and leaves nothing behind."""
    out = tmp_path / "out" / "m.onnx"
    code = _export_int8(setup, out, "--calib", str(setup["data"]), weights="outlier")
    printed = capsys.readouterr()
    assert code == 2 and "INT8 refused" in printed.err, printed.out + printed.err
    # both graphs' numbers are named
    assert re.search(r"box \d+\.\d\d -> \d+\.\d\d, mask \d+\.\d\d -> \d+\.\d\d", printed.err)
    assert len(printed.err.strip().splitlines()) == 1
    assert not out.exists() and list(out.parent.iterdir()) == []


def test_val_on_onnx_equals_val_on_weights(setup, capsys) -> None:
    def val(weights: Path) -> dict:
        assert main(["val", "--weights", str(weights), "--data", str(setup["data"]), "--json"]) == 0
        return json.loads(capsys.readouterr().out.strip().splitlines()[-1])

    torch_result, onnx_result = val(setup["pt"]), val(setup["fp32"])
    assert torch_result["box"]["map50_95"] > 0.2  # the labels are its own detections
    for kind in ("box", "mask"):
        for key in ("map50_95", "map50"):
            assert abs(torch_result[kind][key] - onnx_result[kind][key]) < 1e-3, (kind, key)


def test_bad_calibration_input(setup, tmp_path: Path, capsys) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "broken.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(SlimsegError, match="no readable images"):
        load_calibration_set(empty)
    with pytest.raises(SlimsegError, match=f"only {FRAMES} readable images, 50 asked"):
        load_calibration_set(setup["images"], 50)
    assert len(load_calibration_set(setup["images"]).paths) == FRAMES  # default: all there are
    with pytest.raises(SlimsegError, match="too old"):
        check_onnxruntime("1.15.1")
    out = tmp_path / "x.onnx"
    argv = ["export", "--weights", "darknet19-yolov3", "--nc", "3", "--imgsz", "64", "--int8"]
    assert main([*argv, "--calib", str(setup["images"]), "--out", str(out)]) == 2
    assert "no INT8 placement" in capsys.readouterr().err
    assert _export_int8(setup, out, "--calib", str(setup["images"])) == 2  # folder, no --int8-val
    assert "--int8-val" in capsys.readouterr().err
    assert _export_int8(setup, out, "--calib", str(empty), "--int8-val", str(setup["data"])) == 2
    assert main(["export", "--weights", str(setup["pt"]), "--int8-target", "onnxruntime"]) == 2
    assert "only apply with --int8" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_bench_adds_int8_with_ratio(setup, capsys) -> None:
    argv = ["bench", "--model", "yolov8n-seg", "--imgsz", "64", "--runs", "1", "--warmup", "0"]
    calib = ["--int8", "--calib", str(setup["images"]), "--calib-images", "2"]
    assert main([*argv, *calib, "--nc", "3"]) == 0
    out = capsys.readouterr().out
    assert "int8_trt/ort_fp32" in out and "int8_ort/ort_fp32" in out, out
    assert "2 calibration frames" in out and "CPU: " in out and "load average" in out
    assert main([*argv, "--int8"]) == 2  # --int8 without --calib


@pytest.mark.slow
def test_int8_onnxruntime_target_file_val_and_predictor(setup, tmp_path: Path, capsys) -> None:
    """--int8-target onnxruntime: uint8 activations, int8 weights, int32 biases, Q/DQ on the
    whole body but not on the head's output end; the target in metadata and sidecar; the
    predictor and slimseg val read it; TensorRT's build script refuses it."""
    out = tmp_path / "m-int8-ort.onnx"
    extra = ("--calib", str(setup["data"]), "--int8-max-drop", "100")
    code = _export_int8(setup, out, *extra, "--int8-target", "onnxruntime")
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "int8 Q/DQ for onnxruntime" in printed.out
    proto = onnx.load(str(out))
    g = proto.graph
    inits = {t.name: numpy_helper.to_array(t) for t in g.initializer}
    producers = {o: n for n in g.node for o in n.output}
    qs = [n for n in g.node if n.op_type == "QuantizeLinear"]
    assert qs and all(inits[q.input[2]].dtype == np.uint8 for q in qs)  # activations
    assert any(inits[q.input[2]].any() for q in qs)  # asymmetric: zero points not all 0
    # every conv of the body takes dequantized int8 weights and an int32 bias; the plain
    # predictor convs (no /conv/ block) and the DFL keep float weights
    for conv in (n for n in g.node if n.op_type == "Conv"):
        if re.search(r"/conv(_\d+)?/Conv$", conv.name):
            dq_w, dq_b = producers[conv.input[1]], producers[conv.input[2]]
            assert inits[dq_w.input[0]].dtype == np.int8, conv.name
            assert inits[dq_b.input[0]].dtype == np.int32, conv.name
        else:
            assert inits[conv.input[1]].dtype == np.float32, conv.name
    ops = {producers[o].op_type for o in ("output0", "output1")}
    assert ops == {"Concat", "DequantizeLinear"}  # output0 in float; prototypes quantized
    meta = from_metadata_props({p.key: p.value for p in proto.metadata_props})
    assert meta == json.loads(out.with_suffix(".json").read_text())
    assert meta["precision"] == "int8" and meta["int8"]["target"] == "onnxruntime"
    assert meta["int8"]["quantization"]["activations"].startswith("uint8")
    assert meta["int8"]["quantized_ops"]["Conv"] >= 60
    predictor = Predictor.from_path(out)
    assert predictor.int8_target == "onnxruntime" and "int8 for onnxruntime" in repr(predictor)
    frame = cv2.imread(str(next(setup["images"].iterdir())))[:, :, ::-1].copy()
    assert predictor.predict(frame, conf=0.3).boxes.shape[1] == 4
    assert main(["val", "--weights", str(out), "--data", str(setup["data"])]) == 0
    assert "(int8, onnxruntime target) on" in capsys.readouterr().out
    script = Path(__file__).resolve().parents[2] / "export" / "build_engine.sh"
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "trtexec").write_text("#!/usr/bin/env bash\necho TensorRT v100300\n")
    (bin_dir / "trtexec").chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(["bash", str(script), str(out)], env=env, capture_output=True, text=True)
    assert done.returncode == 2 and "--int8-target tensorrt" in done.stderr


def test_int8_onnxruntime_gate_refuses(setup, tmp_path: Path, capsys, monkeypatch) -> None:
    """The same gate holds for the onnxruntime target: an INT8 graph scored 1.5 points under
    FP32 (a stand-in evaluator: on this fixture's near-constant random network, real INT8
    noise moves mAP either way) is refused with both numbers, and nothing is written."""

    def fake_score(path: Path, *args, **kwargs) -> dict:
        m = 0.30 if path.name == "fp32.onnx" else 0.285
        return {"box": {"map50_95": m}, "mask": {"map50_95": m}, "per_class": []}

    monkeypatch.setattr("slimseg.deploy.int8_export.score_onnx", fake_score)
    out = tmp_path / "out" / "m.onnx"
    argv = ("--calib", str(setup["images"]), "--calib-images", "2", "--int8-val")
    code = _export_int8(setup, out, *argv, str(setup["data"]), "--int8-target", "onnxruntime")
    err = capsys.readouterr().err
    assert code == 2 and "INT8 refused (onnxruntime target)" in err, err
    assert "box 30.00 -> 28.50, mask 30.00 -> 28.50" in err
    assert not out.exists() and list(out.parent.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize("target", ["tensorrt", "onnxruntime"])
def test_entropy_calibration_is_not_minmax(
    setup, tmp_path: Path, target: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Entropy searches a clipping window per tensor (quantize_static's own entropy
    calibrator, 128 bins for 128 levels, can only return the full range: minmax's). Kept
    small for CI: 2 frames and 512 histogram bins instead of the shipped 2048 (129 clipping
    windows searched per tensor instead of 897, each over a 4x shorter histogram)."""
    monkeypatch.setattr("slimseg.deploy.int8_quantize.ENTROPY_BINS", 512)
    calib = load_calibration_set(setup["images"], 2)
    scales = {}
    for method in ("minmax", "entropy"):
        out = tmp_path / f"{method}.onnx"
        quantize_onnx(
            setup["fp32"], out, calib, (IMGSZ, IMGSZ), "yolov8", method, False, None, target
        )
        g = onnx.load(str(out)).graph
        inits = {t.name: numpy_helper.to_array(t) for t in g.initializer}
        q = [n for n in g.node if n.op_type == "QuantizeLinear"]
        scales[method] = np.array([float(inits[n.input[1]]) for n in q])
    assert scales["entropy"].shape == scales["minmax"].shape
    assert (scales["entropy"] < scales["minmax"] * 0.999).sum() >= len(scales["minmax"]) // 4


@pytest.mark.parametrize(
    ("version", "precision", "flags"),
    [
        ("v8601", "int8", ["--int8", "--fp16"]),
        ("v100300", "int8", ["--int8", "--fp16"]),
        ("v110000", "int8", ["--stronglyTyped"]),
        ("v100300", "fp32", ["--fp16"]),
        ("v100300", "fp16", ["--fp16"]),
        ("v110000", "fp16", ["--stronglyTyped"]),  # TensorRT 11 refuses --fp16
        ("v110000", "fp32", ["--stronglyTyped"]),
    ],
)
def test_build_engine_flags(tmp_path: Path, version: str, precision: str, flags: list) -> None:
    """build_engine.sh picks its precision flags by the sidecar's precision and the TensorRT
    version (a stand-in trtexec records its arguments)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "trtexec"
    fake.write_text(
        f'#!/usr/bin/env bash\nif [ "$1" = --help ]; then echo "TensorRT {version}"; exit 0; fi\n'
        f'echo "$@" > {tmp_path / "args.txt"}\n'
    )
    fake.chmod(0o755)
    (tmp_path / "m.onnx").write_bytes(b"")
    meta = {"imgsz": [64, 64], "dynamic_shapes": False, "precision": precision}
    (tmp_path / "m.json").write_text(json.dumps(meta))
    script = Path(__file__).resolve().parents[2] / "export" / "build_engine.sh"
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}
    subprocess.run(
        ["bash", str(script), str(tmp_path / "m.onnx")], check=True, env=env, capture_output=True
    )
    args = (tmp_path / "args.txt").read_text().split()
    assert [a for a in args if a in ("--int8", "--fp16", "--stronglyTyped")] == flags
