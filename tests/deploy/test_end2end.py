"""``slimseg export --end2end``: NMS and masks inside the graph, in ``ai.onnx`` operators only,
giving ``slimseg predict``'s instances (FP32, dynamic batch 2, FP16 against FP32), read by the
Predictor and ``slimseg.Masker`` without torch, and refused where it cannot apply."""

from __future__ import annotations

import copy
import json
import os
import subprocess
import warnings
from pathlib import Path

import numpy as np
import onnx
import onnxslim
import pytest
import torch
from conftest import batchnorm_from, have_cpp_toolchain, open_class_bias
from test_core_install import BLOCK, _python

from slimseg.cli.main import main
from slimseg.data.synth.scene import STREAM_VAL, render_image
from slimseg.deploy.end2end_graph import PREFIX, End2EndSettings, append_end2end
from slimseg.deploy.end2end_parity import (
    FP16_MATCH_FRACTION,
    MATCH_FRACTION,
    box_iou,
    gate_frames,
    match_predictions,
    verify_end2end,
)
from slimseg.deploy.metadata import build_metadata, with_end2end
from slimseg.deploy.onnx_export import output_names, to_fp16
from slimseg.deploy.onnx_io import publish, stage, staging_dir
from slimseg.deploy.parity import ExportParityError
from slimseg.deploy.predictor import Predictor
from slimseg.deploy.preprocess import preprocess_frame
from slimseg.deploy.raw_dump import frame_dump, read_raw, write_raw
from slimseg.deploy.trt_ops import DYNAMIC_SHAPE_OPS, END2END_OPS, TENSORRT_SUPPORTED_OPS
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.models.registry import build_model

NAMES = ["person", "chair", "car"]
MOBILITY = [1.0, 0.1, 0.3]
IMGSZ = (160, 160)
MAX_DET = 60
SETTINGS = End2EndSettings(conf=0.1, iou=0.7, max_det=MAX_DET)


def scored_model(name: str = "yolov8n-seg", imgsz: tuple[int, int] = IMGSZ) -> torch.nn.Module:
    """A random ``name`` with BatchNorm statistics of the gate frames and class biases shifted
    so that about 0.2 % of the anchor-class scores exceed 0.5: tens of detections per frame
    (a random head scores nothing, or everything)."""
    torch.manual_seed(0)
    model = build_model(name, num_classes=len(NAMES))
    frames = [preprocess_frame(f, imgsz)[0] for f in gate_frames(imgsz)]
    batch = torch.from_numpy(np.concatenate(frames))
    model = open_class_bias(batchnorm_from(model, batch)).eval()
    with torch.no_grad():
        out = model(batch)
        scores = (out[0] if isinstance(out, tuple) else out)[:, 4 : 4 + len(NAMES)]
        shift = torch.logit(scores.clamp(1e-6, 1 - 1e-6)).flatten().quantile(0.998)
        for branch in model.detect.cls:
            branch[-1].bias -= shift
    return model


def _raw_exports(model, root: Path) -> dict[str, Path]:
    """The raw graph as ``slimseg export`` traces it, FP32 and FP16, static (no parity gate: an
    FP16 random head would not pass the raw FP16 gate, which is not what these tests are
    about)."""
    fused = model.fuse().float().eval()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traced = root / "traced.onnx"
        torch.onnx.export(
            fused, torch.zeros(1, 3, *IMGSZ), str(traced), input_names=["images"],
            output_names=output_names(fused), opset_version=18, dynamo=False,
        )  # fmt: skip
    proto = onnxslim.slim(onnx.load(str(traced)))  # as slimseg export does
    out = {}
    for key, precision in (("raw32", "fp32"), ("raw16", "fp16")):
        path = root / f"{key}.onnx"
        meta = build_metadata(fused, NAMES, MOBILITY, IMGSZ, precision)
        graph = to_fp16(copy.deepcopy(proto)) if precision == "fp16" else proto
        with staging_dir(path) as tmp:
            publish(stage(graph, meta, tmp, path.name), meta, path)
        out[key] = path
    return out


def _end2end_of(raw: Path, out: Path, settings: End2EndSettings = SETTINGS, meta_settings=None):
    """``raw`` with the end-to-end sub-graph of ``settings``; its metadata says
    ``meta_settings`` (default: the same)."""
    proto = onnx.load(str(raw))
    meta = json.loads(raw.with_suffix(".json").read_text())
    batch, anchors = "batch", None
    if not meta["dynamic_shapes"]:
        batch, anchors = 1, sum((IMGSZ[0] // s) * (IMGSZ[1] // s) for s in meta["strides"])
    append_end2end(proto, len(NAMES), int(meta["num_masks"]), settings, batch, anchors)
    meta = with_end2end(meta, (meta_settings or settings).as_dict())
    with staging_dir(out) as tmp:
        publish(stage(proto, meta, tmp, out.name), meta, out)
    return out


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """FP32 (``slimseg export --end2end --dynamic``: the gate ran) and FP16 end-to-end files,
    and the raw graphs they come from."""
    root = tmp_path_factory.mktemp("end2end")
    model = scored_model()
    info = WeightsInfo(model.spec, NAMES, MOBILITY, train_config={"imgsz": IMGSZ[0]})
    weights = save_weights(root / "w.pt", model, info)
    e2e = root / "e2e.onnx"
    args = ["export", "--weights", str(weights), "--imgsz", "160", "--end2end", "--dynamic"]
    assert main([*args, "--max-det", str(MAX_DET), "--out", str(e2e)]) == 0
    raws = _raw_exports(model, root)
    return {
        "fp32": e2e,
        **raws,
        "fp16": _end2end_of(raws["raw16"], root / "e2e16.onnx"),
    }


def _predict(path: Path, frames, batch: bool = False):
    p = Predictor.from_path(path, threads=1)
    if batch:
        return p.predict_batch(frames, conf=0.25, iou=0.7, max_det=MAX_DET)
    return [p.predict(f, conf=0.25, iou=0.7, max_det=MAX_DET) for f in frames]


def test_end2end_instances_equal_predicts_raw_path(files, capsys) -> None:
    frames = gate_frames(IMGSZ)
    refs = _predict(files["raw32"], frames)
    single = match_predictions(refs, _predict(files["fp32"], frames))
    batch2 = match_predictions(refs, _predict(files["fp32"], frames, batch=True))
    print(f"\nfp32 {single}\nbatch2 {batch2}")
    assert single["detections"] >= 20  # a model with real work for the NMS
    assert single["fraction"] >= MATCH_FRACTION and batch2["fraction"] >= MATCH_FRACTION
    assert single["min_mask_iou"] >= 0.9 and single["max_score_diff"] <= 0.02
    # the raw FP16 path and the FP16 end-to-end graph against the FP32 end-to-end graph
    ref32 = _predict(files["fp32"], frames)
    fp16 = match_predictions(ref32, _predict(files["fp16"], frames))
    print(f"fp16 vs fp32 {fp16}")
    assert fp16["fraction"] >= FP16_MATCH_FRACTION
    assert (
        match_predictions(_predict(files["raw16"], frames), _predict(files["fp16"], frames))[
            "fraction"
        ]
        >= MATCH_FRACTION
    )


def test_the_graph_uses_standard_operators_and_the_contract_tensors(files) -> None:
    model = onnx.load(str(files["fp32"]))
    assert {n.domain for n in model.graph.node} <= {"", "ai.onnx"}
    ops = {n.op_type for n in model.graph.node}
    assert {"NonMaxSuppression", "TopK", "MatMul", "GatherND"} <= ops
    post = {n.op_type for n in model.graph.node if n.name.startswith(PREFIX)}
    assert post <= END2END_OPS, post - END2END_OPS
    assert ops <= TENSORRT_SUPPORTED_OPS | DYNAMIC_SHAPE_OPS | END2END_OPS
    outs = {o.name: o.type.tensor_type for o in model.graph.output}
    assert list(outs) == ["num_dets", "boxes", "scores", "classes", "masks"]
    dims = {k: [d.dim_param or d.dim_value for d in t.shape.dim] for k, t in outs.items()}
    assert dims["boxes"] == ["batch", MAX_DET, 4] and dims["masks"][:2] == ["batch", MAX_DET]
    meta = json.loads(files["fp32"].with_suffix(".json").read_text())
    assert meta["end2end"]["max_det"] == MAX_DET and meta["end2end"]["conf"] == 0.1
    # FP16: the network and the masks in float16; boxes, scores and the NMS inputs in float32
    half = onnx.load(str(files["fp16"]))
    types = {o.name: o.type.tensor_type.elem_type for o in half.graph.output}
    assert types["masks"] == onnx.TensorProto.FLOAT16
    assert types["boxes"] == types["scores"] == onnx.TensorProto.FLOAT
    inferred = onnx.shape_inference.infer_shapes(half).graph.value_info
    nms = next(n for n in half.graph.node if n.op_type == "NonMaxSuppression")
    elem = {v.name: v.type.tensor_type.elem_type for v in inferred}
    assert elem[nms.input[0]] == elem[nms.input[1]] == onnx.TensorProto.FLOAT
    floats = [i.data_type for i in half.graph.initializer if i.data_type in (1, 10)]
    assert floats.count(onnx.TensorProto.FLOAT16) > 0.8 * len(floats)


def test_the_gate_refuses_a_graph_that_drops_detections(files, tmp_path) -> None:
    # NMS at conf 0.5 inside, metadata claiming 0.1: the 0.25..0.5 detections are missing
    bad = _end2end_of(
        files["raw32"], tmp_path / "bad.onnx", End2EndSettings(0.5, 0.7, MAX_DET), SETTINGS
    )
    with pytest.raises(ExportParityError, match=r"end-to-end graph .* kept"):
        verify_end2end(files["raw32"], bad, IMGSZ, dynamic=False)


def test_masker_runs_an_end2end_export_without_torch(files) -> None:
    code = (
        f"{BLOCK}\nimport numpy as np, slimseg\n"
        f"m = slimseg.Masker.from_onnx({str(files['fp32'])!r}, threads=1, conf=0.2)\n"
        "rng = np.random.default_rng(0)\n"
        "out = m.step(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))\n"
        "assert m.predictor.end2end and out.mask.shape == (120, 160)\n"
        "assert 'torch' not in sys.modules and 'onnx' not in sys.modules\n"
    )
    done = _python(code)
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--end2end", "--int8", "--calib", "x"], "--end2end goes without --int8"),
        (["--max-det", "10"], "only apply with --end2end"),
        (["--end2end", "--weights", "msnet-t"], "has no end-to-end graph"),
    ],
)
def test_end2end_refusals(args, message, tmp_path, capsys) -> None:
    argv = ["export", "--weights", "yolov8n-seg", "--nc", "3", "--imgsz", "64"]
    assert main([*argv, *args, "--out", str(tmp_path / "m.onnx")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "m.onnx").exists()


def test_val_refuses_an_end2end_export(files) -> None:
    from slimseg.deploy.onnx_model import OnnxModel
    from slimseg.errors import SlimsegError

    with pytest.raises(SlimsegError, match="end-to-end export"):
        OnnxModel(files["fp32"])
    assert copy.deepcopy(SETTINGS) == SETTINGS


def _cpp_results(example: Path, predictor: Predictor, frames, folder: Path, conf: float):
    """Dump ``frames`` through ``predictor`` (raw or end-to-end outputs) and run the C++
    example on the dumps; its results per frame."""
    dumps, out = folder / "dumps", folder / "out"
    dumps.mkdir(parents=True)
    (dumps / "metadata.json").write_text(json.dumps(predictor.metadata))
    rng = np.random.default_rng(0)
    for i, image in enumerate(frames):
        (h, w), raw = image.shape[:2], {}
        predictor.predict(image, conf=1.0, raw=raw)
        kps = rng.uniform((0, 0), (w, h), (100, 2)).astype(np.float32)
        write_raw(dumps / f"f{i}.ssraw", frame_dump(raw, (h, w), kps))
    cmd = [str(example), "--meta", str(dumps / "metadata.json"), "--dumps", str(dumps)]
    cmd += ["--conf", str(conf), "--max-det", str(MAX_DET), "--results"]
    done = subprocess.run([*cmd, "--out", str(out)],
                          capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 0, done.stderr
    return [read_raw(out / f"f{i}.ssres") for i in range(len(frames))]


@pytest.mark.skipif(not have_cpp_toolchain(), reason="needs cmake and a C++ compiler")
def test_cpp_consumer_reads_end2end_outputs_like_the_raw_ones(example, files, tmp_path) -> None:
    gate = gate_frames(IMGSZ, 2)
    # no resize (160 x 160), letterboxed 4:3, non-multiples of 32 and upscaled
    square = render_image(0, 5, 160, STREAM_VAL).rgb
    frames = [square, gate[0], gate[1][:97, :131], gate[0][:50, :70]]
    e2e = Predictor.from_path(files["fp32"], threads=1)
    conf = 0.25
    cpp_e2e = _cpp_results(example, e2e, frames, tmp_path / "e2e", conf)
    cpp_raw = _cpp_results(example, Predictor.from_path(files["raw32"], threads=1), frames,
                           tmp_path / "raw", conf)  # fmt: skip
    total = 0
    for i, image in enumerate(frames):
        py = e2e.predict(image, conf=conf, iou=0.7, max_det=MAX_DET)
        got, ref = cpp_e2e[i], cpp_raw[i]
        total += len(py.scores)
        np.testing.assert_array_equal(got["classes"], py.classes)
        np.testing.assert_array_equal(got["scores"], py.scores)
        np.testing.assert_allclose(got["boxes"], py.boxes, rtol=0, atol=1e-3)
        np.testing.assert_array_equal(got["masks"] > 0, py.masks)  # same probabilities, same rule
        for key in ("classes", "scores", "boxes"):  # the raw path in C++
            np.testing.assert_array_equal(got[key], ref[key], err_msg=f"frame {i} {key}")
        # the graph and the C++ raw path compute the same mask probabilities in another order:
        # a pixel at the threshold may round either way (1 of 1.5 M once, on a model whose
        # statistics came from another thread count), and a keypoint on it with it
        flipped = got["masks"] != ref["masks"]
        assert flipped.mean() <= 1e-5, f"frame {i}: {flipped.sum()} mask pixels differ"
        assert (got["dynamic"] != ref["dynamic"]).sum() <= flipped.sum(), f"frame {i}"
    assert total >= 10


@pytest.mark.parametrize(("version", "code"), [("v8500", 2), ("v8601", 0), ("v110000", 0)])
def test_build_engine_takes_end2end_files_from_tensorrt_8_6(tmp_path, version, code) -> None:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "trtexec"
    fake.write_text(f'#!/usr/bin/env bash\n[ "$1" = --help ] && echo "TensorRT {version}"\ntrue\n')
    fake.chmod(0o755)
    (tmp_path / "m.onnx").write_bytes(b"")
    meta = {"imgsz": [64, 64], "dynamic_shapes": False, "precision": "fp16", "end2end": {}}
    (tmp_path / "m.json").write_text(json.dumps(meta))
    script = Path(__file__).resolve().parents[2] / "export" / "build_engine.sh"
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(["bash", str(script), str(tmp_path / "m.onnx")], env=env,
                          capture_output=True, text=True)  # fmt: skip
    assert done.returncode == code, done.stderr
    assert code == 0 or "needs TensorRT >= 8.6" in done.stderr


@pytest.mark.parametrize("key", ["fp32", "fp16"])
def test_opencv_dnn_runs_the_end2end_graph(files, key) -> None:
    import cv2
    import onnxruntime as ort

    x = preprocess_frame(gate_frames(IMGSZ, 1)[0], IMGSZ)[0]
    x = x.astype(np.float16) if key == "fp16" else x
    net = cv2.dnn.readNetFromONNX(str(files[key]))
    net.setInput(x)
    names = list(net.getUnconnectedOutLayersNames())
    got = dict(zip(names, net.forward(names), strict=True))
    session = ort.InferenceSession(str(files[key]), providers=["CPUExecutionProvider"])
    ref = dict(zip([o.name for o in session.get_outputs()], session.run(None, {"images": x}),
                   strict=True))  # fmt: skip
    n = int(ref["num_dets"][0])
    assert n > 0
    np.testing.assert_array_equal(got["num_dets"], ref["num_dets"])
    if key == "fp32":
        np.testing.assert_array_equal(got["classes"], ref["classes"])
        np.testing.assert_allclose(got["boxes"], ref["boxes"], rtol=0, atol=2e-3)
        np.testing.assert_allclose(got["masks"], ref["masks"], rtol=0, atol=1e-3)
        return
    # FP16: rounding reorders near-equal scores; every row has its counterpart
    same = ref["classes"][0, :n, None] == got["classes"][0, None, :n]
    iou = np.where(same, box_iou(ref["boxes"][0, :n], got["boxes"][0, :n]), 0)
    assert iou.max(1).min() >= 0.99


def test_detector_end2end_at_opset_17(tmp_path) -> None:
    """A detector (no masks output) at the lowest opset (ReduceMax's axes an attribute)."""
    out = tmp_path / "det.onnx"
    argv = ["export", "--weights", "yolov8n", "--nc", "3", "--imgsz", "32", "--opset", "17"]
    assert main([*argv, "--end2end", "--max-det", "5", "--out", str(out)]) == 0
    model = onnx.load(str(out))
    assert [o.name for o in model.graph.output] == ["num_dets", "boxes", "scores", "classes"]
    predictor = Predictor.from_path(out, threads=1)
    pred = predictor.predict(gate_frames((32, 32), 1)[0], conf=0.1, iou=0.7, max_det=5)
    assert predictor.end2end and pred.masks is None and len(pred.scores) <= 5
