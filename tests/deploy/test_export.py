"""ONNX export: parity for every variant, TensorRT-safe ops, metadata, nothing half-written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from conftest import randomize_batchnorm
from torch import nn

from slimseg.cli.main import main
from slimseg.deploy import onnx_export, parity
from slimseg.deploy.metadata import from_metadata_props
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.parity import ExportParityError
from slimseg.deploy.tolerances import FP32_BOX_TOL, FP32_LOGIT_TOL, FP32_SCORE_TOL
from slimseg.deploy.trt_ops import DATA_DEPENDENT_OPS, DYNAMIC_SHAPE_OPS, TENSORRT_SUPPORTED_OPS
from slimseg.models.registry import build_model, list_models


def _realistic(name: str, nc: int = 5) -> nn.Module:
    """Random weights with non-trivial BN statistics and unsaturated class scores."""
    model = randomize_batchnorm(build_model(name, num_classes=nc)).eval()
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, nn.Conv2d) and m.bias is not None and m.out_channels == nc:
                m.bias.zero_()
    return model


@pytest.mark.parametrize("name", list_models())
def test_every_variant_exports_with_parity_and_tensorrt_ops(name: str, tmp_path: Path) -> None:
    imgsz = (128, 160)
    report = export_onnx(_realistic(name), tmp_path / f"{name}.onnx", imgsz, ["a"] * 5, [1.0] * 5)
    assert set(report.ops) <= TENSORRT_SUPPORTED_OPS, set(report.ops) - TENSORRT_SUPPORTED_OPS
    assert not set(report.ops) & DATA_DEPENDENT_OPS
    proto = onnx.load(str(report.path))
    dims = [[d.dim_value for d in o.type.tensor_type.shape.dim] for o in proto.graph.output]
    if name.startswith("msnet"):  # semantic logits (tests/models/test_msnet.py checks more)
        assert report.parity["input1/logit"] <= FP32_LOGIT_TOL.atol
        assert dims == [[1, 5 + 1, 128, 160]]
        return
    assert report.parity["input1/box_px"] <= FP32_BOX_TOL.atol
    assert report.parity["input1/score"] <= FP32_SCORE_TOL.atol
    a = sum((128 // s) * (160 // s) for s in (8, 16, 32))
    if name.startswith("yolov8") and "seg" in name:
        stride = build_model(name).spec.head.proto_stride
        assert dims == [[1, 4 + 5 + 32, a], [1, 32, 128 // stride, 160 // stride]]
    elif name.startswith("yolov8"):
        assert dims == [[1, 4 + 5, a]]
    else:
        assert dims == [[1, 5 + 5, 3 * a]]


def test_metadata_and_sidecar(tmp_path: Path) -> None:
    model = build_model("yolov8n-seg-gs-rep", num_classes=3)
    names, mobility = ["person", "ball", "chair"], [1.0, 0.75, 0.25]
    report = export_onnx(model, tmp_path / "m.onnx", (96, 96), names, mobility)
    proto = onnx.load(str(report.path))
    meta = from_metadata_props({p.key: p.value for p in proto.metadata_props})
    assert meta == json.loads(report.sidecar.read_text())
    assert meta["names"] == names and meta["mobility"] == mobility
    assert meta["dynamic_classes"] == [0, 1] and meta["imgsz"] == [96, 96]
    assert meta["spec_hash"] == model.spec.hash and meta["num_masks"] == 32
    assert meta["letterbox"]["pad_value"] == 114 and meta["input"]["color"] == "RGB"
    assert set(meta["outputs"]) == {"output0", "output1"}
    # the precision the parity holds at, and each engine's default and how to ask for FP32
    assert meta["parity"]["arithmetic"] == "fp32"
    defaults = meta["parity"]["engine_defaults"]
    assert {"onnxruntime", "opencv_dnn", "tensorrt", "openvino_arm"} <= set(defaults)
    assert "INFERENCE_PRECISION_HINT=f32" in defaults["openvino_x86_amx_or_avx512_bf16"]


def test_fp16_export_matches_detections(tmp_path: Path) -> None:
    report = export_onnx(_realistic("yolov8n-seg"), tmp_path / "h.onnx", (128, 128), half=True)
    proto = onnx.load(str(report.path))
    assert proto.graph.input[0].type.tensor_type.elem_type == onnx.TensorProto.FLOAT16
    assert proto.graph.output[0].type.tensor_type.elem_type == onnx.TensorProto.FLOAT16
    assert report.parity["input1/matched"] == report.parity["input1/checked"] > 0


def test_dynamic_export_runs_other_batch_and_sizes(tmp_path: Path) -> None:
    model = _realistic("yolov8n-seg")
    report = export_onnx(model, tmp_path / "d.onnx", (128, 128), dynamic=True)
    assert set(report.ops) <= TENSORRT_SUPPORTED_OPS | DYNAMIC_SHAPE_OPS
    # the export's own gate checked batch 2 and a second size, every output
    for tag in ("batch2", "size160x192"):
        assert {f"{tag}/{k}" for k in ("box_px", "score", "mask_terms")} <= set(report.parity)
    session = ort.InferenceSession(str(report.path), providers=["CPUExecutionProvider"])
    x = np.random.default_rng(0).random((2, 3, 96, 160), dtype=np.float32)
    got = session.run(None, {"images": x})
    with torch.no_grad():
        ref = model.fuse()(torch.from_numpy(x))
    assert got[0].shape == tuple(ref[0].shape) and got[1].shape == tuple(ref[1].shape)
    # every row of output0 (boxes, scores, mask coefficients) and the prototypes
    parity.check_fp32_parity(model, [r.numpy() for r in ref], got)


@pytest.mark.slow
def test_dynamic_parity_catches_a_size_dependent_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A graph right at the export size but wrong at another size is refused."""
    real = parity.cpu_session

    class Skewed:
        def __init__(self, session) -> None:
            self.session = session
            self.get_inputs = session.get_inputs

        def run(self, names, feed):
            outs = self.session.run(names, feed)
            if feed["images"].shape[2:] != (64, 64):
                outs[0] = outs[0] + 0.5
            return outs

    monkeypatch.setattr(parity, "cpu_session", lambda path: Skewed(real(path)))
    with pytest.raises(ExportParityError):
        export_onnx(_realistic("yolov8n"), tmp_path / "s.onnx", (64, 64), dynamic=True)
    assert not (tmp_path / "s.onnx").exists()


def test_parity_failure_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(fused: nn.Module, path: Path, imgsz: tuple, half: bool) -> dict:
        raise ExportParityError("simulated mismatch")

    monkeypatch.setattr(onnx_export, "verify_parity", broken)
    out = tmp_path / "x.onnx"
    with pytest.raises(ExportParityError):
        export_onnx(build_model("yolov8n", num_classes=2), out, (64, 64))
    assert list(tmp_path.iterdir()) == []


def test_fp32_parity_check_catches_a_shift() -> None:
    model = build_model("yolov8n", num_classes=2)
    ref = [np.zeros((1, 6, 10), np.float32)]
    got = [ref[0].copy()]
    got[0][0, 0, 3] += 0.5  # half a pixel off
    with pytest.raises(ExportParityError, match=r"output0 boxes \(box_px\) at \[0, 0, 3\]"):
        parity.check_fp32_parity(model, ref, got)


def test_export_cli_and_errors(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "c.onnx"
    argv = ["export", "--weights", "yolov8n-seg", "--nc", "4", "--imgsz", "96", "128"]
    assert main([*argv, "--out", str(out)]) == 0
    assert out.is_file() and out.with_suffix(".json").is_file()
    assert "parity vs fused torch" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:  # argparse's one line: not a multiple of 32
        main(["export", "--weights", "yolov8n", "--imgsz", "100", "--out", str(out)])
    assert exc.value.code == 2
    assert main(["export", "--weights", "yolov8n", "--opset", "13", "--out", str(out)]) == 2


def test_bench_reports_every_form(capsys: pytest.CaptureFixture) -> None:
    argv = ["bench", "--model", "yolov8n-seg", "yolov8n-seg-gs-rep", "--imgsz", "64"]
    assert main([*argv, "--runs", "1", "--warmup", "0", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    for name in ("yolov8n-seg", "yolov8n-seg-gs-rep"):
        assert set(result[name]) == {"torch", "torch_fused", "ort_fp32", "ort_fp16", "postprocess"}
        assert all(v > 0 for v in result[name].values())
