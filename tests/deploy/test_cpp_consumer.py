"""The C++ reference consumer (export/cpp) against the Python reference, on the same raw outputs.

The library and its example are built once per session with CMake and the machine's C++
compiler; each model's raw onnxruntime outputs are dumped (``slimseg.deploy.raw_dump``) and
the example's results compared with ``Predictor`` (boxes, scores, classes, masks, class maps)
and with the masking logic ``slimseg dynamic`` runs (``process_frame``: the dynamic mask, the
dynamic keypoints and Eq. 1's threshold).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
import torch
from conftest import batchnorm_from, disc_scene, have_cpp_toolchain, open_class_bias

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.deploy.metadata import build_metadata, masking_from_metadata
from slimseg.deploy.onnx_export import output_names, to_fp16
from slimseg.deploy.onnx_io import publish, stage, staging_dir
from slimseg.deploy.predictor import Predictor
from slimseg.deploy.preprocess import preprocess_frame
from slimseg.deploy.raw_dump import frame_dump, read_raw, write_raw
from slimseg.detections import Prediction
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.masking_settings import PAPERS, MaskingSettings
from slimseg.dynamic.pipeline import FrameResult, FrameRules, process_frame
from slimseg.dynamic.semantic import objects_of
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.models.registry import build_model

NAMES = ["person", "chair", "car"]
MOBILITY = [1.0, 0.1, 0.3]
# Masking settings the tests write into the metadata (read back by both sides): the default
# entry and extra presets, chosen so that the frames below see every outcome of Eq. 1 (the
# start threshold, a raised one, giving up) besides frames without detections.
TEST_MASKING = {"min_static": 60, "dilation_px": 3, "frame_ratio": 0.05, "t_o": 0.4}
# "raise" and "wide" use Eq. 1 (papers' rule: no "rule" key); the default entry and "shed" the
# degrading rule, "shed" short of support on some frames so that it gives masks up.
TEST_PRESETS = {"raise": {**TEST_MASKING, "min_static": 110}, "wide": {**TEST_MASKING,
                "dilation_px": 7, "m_th_step": 0.2, "t_o": 0.9, "cut_behind_m": 0.2},
                "shed": {**TEST_MASKING, "min_static": 150, "rule": "degrade",
                         "keep_score": 0.3, "cut_behind_m": 0.5}}  # fmt: skip
# Frame sizes (h, w): the input's own, landscape, portrait, non-multiples of 32, upscaled.
SIZES = [(160, 160), (120, 200), (200, 120), (97, 131), (50, 70)]
KEYPOINTS = 200  # caller-given keypoints per frame (uniform, a quarter on half-pixel ties)


pytestmark = pytest.mark.skipif(not have_cpp_toolchain(), reason="needs cmake and a C++ compiler")


def _scene(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """RGB uint8 ``[h, w, 3]``: a gradient, discs and a rectangle on each border."""
    img = disc_scene(rng, h, w, 5)
    t = max(min(h, w) // 5, 4)
    for sl in ((slice(0, t), slice(None)), (slice(h - t, h), slice(None))):
        img[sl] = rng.random(3, dtype=np.float32)
    for sl in ((slice(None), slice(0, t)), (slice(None), slice(w - t, w))):
        img[sl] = rng.random(3, dtype=np.float32)
    return (img * 255).astype(np.uint8)


def _frames(sizes=SIZES) -> list[np.ndarray]:
    """The test frames (RGB uint8), one per size: the models are calibrated on them too, as a
    trained model is on its domain."""
    rng = np.random.default_rng(1)
    return [_scene(rng, h, w) for h, w in sizes]


def _depth(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A depth image (m) for the depth cut: a floor from 1 m (top) to 5 m (bottom), blocks at
    1-3 m, holes (0, NaN)."""
    depth = np.repeat(np.linspace(1.0, 5.0, h, dtype=np.float32)[:, None], w, 1)
    for _ in range(4):
        y, x = rng.integers(0, h), rng.integers(0, w)
        dy, dx = rng.integers(h // 8, h // 2), rng.integers(w // 8, w // 2)
        depth[y : y + dy, x : x + dx] = rng.uniform(1.0, 3.0)
    holes = rng.random((h, w))
    depth[holes < 0.03] = 0.0
    depth[holes > 0.98] = np.nan
    return depth


def _sparse_scores(model: torch.nn.Module, batch: torch.Tensor, top: float = 0.998) -> None:
    """Shift the class-logit biases so that about ``1 - top`` of the anchor-class scores of
    ``batch`` exceed 0.5 (BatchNorm-calibrated random heads score nearly everything ~1: every
    mask would cover the frame and Eq. 1 would have nothing to choose)."""
    with torch.no_grad():
        out = model(batch)
        scores = (out[0] if isinstance(out, tuple) else out)[:, 4 : 4 + len(NAMES)]
        shift = torch.logit(scores.clamp(1e-6, 1 - 1e-6)).flatten().quantile(top)
        for branch in model.detect.cls:
            branch[-1].bias -= shift


def _export(out: Path, name: str, imgsz: tuple[int, int], half: bool) -> Path:
    """A randomly initialised ``name`` with BatchNorm statistics of the letterboxed test frames
    and sparse class scores (:func:`_sparse_scores`), fused and exported as ``out`` + sidecar,
    FP16 on request; no parity gate: the comparisons run on what onnxruntime gives."""
    torch.manual_seed(0)
    model = build_model(name, num_classes=len(NAMES))
    frames = [preprocess_frame(image, imgsz)[0] for image in _frames()]
    batch = torch.from_numpy(np.concatenate(frames))
    model = batchnorm_from(model, batch)
    if model.spec.family == "yolov8":
        _sparse_scores(open_class_bias(model), batch)
    fused = model.fuse().float().eval()
    meta = build_metadata(fused, NAMES, MOBILITY, imgsz, "fp16" if half else "fp32")
    with staging_dir(out) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = Path(tmp) / "raw.onnx"
        torch.onnx.export(
            fused, torch.zeros(1, 3, *imgsz), str(raw), input_names=["images"],
            output_names=output_names(fused), opset_version=18, dynamo=False,
        )  # fmt: skip
        proto = onnx.load(str(raw))
        publish(stage(to_fp16(proto) if half else proto, meta, tmp, out.name), meta, out)
    return out


@dataclass
class Case:
    """One model's dumps: its predictor, the dump folder (frames, ``.ssraw``, metadata with
    ``TEST_MASKING``) and each frame's RGB image and keypoints."""

    predictor: Predictor
    dumps: Path
    frames: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    """per stem: the RGB frame, its keypoints and its depth (m)"""
    presets: dict[str, MaskingSettings]
    """"" (the default entry), the export's presets and ``TEST_PRESETS``"""
    predictions: dict = field(default_factory=dict)
    """``Predictor.predict`` results by (frame, conf, iou, max_det), computed once"""

    def predict(self, stem: str, conf: float, iou: float, max_det: int) -> Prediction:
        key = stem, conf, iou, max_det
        if key not in self.predictions:
            image = self.frames[stem][0]
            self.predictions[key] = self.predictor.predict(image, conf, iou, max_det)
        return self.predictions[key]


def _dump(root: Path, name: str, imgsz: tuple[int, int], half: bool, sizes=SIZES) -> Case:
    model = _export(root / f"{name}{'-fp16' if half else ''}.onnx", name, imgsz, half)
    predictor = Predictor.from_path(model, threads=1)
    dumps = root / f"dumps-{model.stem}"
    meta = dict(predictor.metadata)
    entry = meta["slam_masking"]
    meta["slam_masking"] = {
        **entry,
        **TEST_MASKING,
        "presets": {**entry["presets"], **TEST_PRESETS},
    }
    dumps.mkdir()
    (dumps / "metadata.json").write_text(json.dumps(meta))
    rng = np.random.default_rng(2)
    frames = {}
    for i, image in enumerate(_frames(sizes)):
        (h, w), raw = image.shape[:2], {}
        predictor.predict(image, conf=1.0, raw=raw)  # the raw outputs only
        kps = rng.uniform((0, 0), (w, h), (KEYPOINTS, 2)).astype(np.float32)
        kps[: KEYPOINTS // 4] = np.floor(kps[: KEYPOINTS // 4]) + 0.5  # rounding ties
        stem = f"f{i}_{h}x{w}"
        depth = _depth(rng, h, w)
        write_raw(dumps / f"{stem}.ssraw", frame_dump(raw, (h, w), kps, depth))
        cv2.imwrite(str(dumps / f"{stem}.ppm"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        frames[stem] = image, kps, depth
    presets = {k: PAPERS.with_values(**v) for k, v in meta["slam_masking"]["presets"].items()}
    return Case(predictor, dumps, frames, {"": masking_from_metadata(meta), **presets})


MODELS = {  # key: (variant, input H x W, FP16)
    "yolov8n-seg fp32": ("yolov8n-seg", (160, 160), False),
    "yolov8n-seg fp16": ("yolov8n-seg", (160, 160), True),
    "yolov8n-seg-hr fp32": ("yolov8n-seg-hr", (128, 192), False),
    "yolov8n fp16": ("yolov8n", (160, 160), True),
    "darknet19-yolov3 fp32": ("darknet19-yolov3", (128, 128), False),
    "msnet-t fp32": ("msnet-t", (128, 128), False),
    "yolov8n-seg 256 fp16": ("yolov8n-seg", (256, 256), True),
}


@pytest.fixture(scope="module")
def cases(tmp_path_factory: pytest.TempPathFactory):
    """``cases(key)``: the :class:`Case` of a ``MODELS`` entry, exported on first use."""
    root = tmp_path_factory.mktemp("cpp_models")
    made: dict[str, Case] = {}

    def get(key: str) -> Case:
        if key not in made:
            folder = root / key.replace(" ", "_")
            folder.mkdir()
            made[key] = _dump(folder, *MODELS[key])
        return made[key]

    return get


def _run(example: Path, case: Case, out: Path, *args: str) -> dict[str, dict[str, np.ndarray]]:
    cmd = [str(example), "--meta", str(case.dumps / "metadata.json"), "--dumps", str(case.dumps)]
    cmd += ["--out", str(out), "--frames", str(case.dumps), "--results", *args]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return {stem: read_raw(out / f"{stem}.ssres") for stem in case.frames}


def _python_dynamic(
    case: Case,
    pred: Prediction,
    kps: np.ndarray,
    depth: np.ndarray | None,
    mode: str,
    preset: str = "",
) -> FrameResult:
    """What ``slimseg dynamic`` does with one frame's prediction (sequence_run, no track)."""
    mobility = np.asarray(case.predictor.mobility, np.float32)
    rules = FrameRules(mobility, mode, case.presets[preset])
    inputs = FrameInputs(kps, objects_of(pred, pred.image_hw), depth_m=depth)
    return process_frame(inputs=inputs, settings=rules)


def _canonical(boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray) -> np.ndarray:
    """Order by decreasing score, ties by class and box (equal scores have no reference order:
    torch's descending sort is not stable)."""
    return np.lexsort((*boxes.T[::-1], classes, -scores.astype(np.float64)))


def _pair_ties(order, ours, theirs, key) -> np.ndarray:
    """``order`` with the detections whose ``key`` rows (score, class, frame box) coincide
    (FP16 outputs: two anchors whose clipped boxes coincide) paired by their masks, ``ours``
    (reference) vs ``theirs``, both in canonical order: nothing else tells them apart."""
    base, out = np.array(order), np.array(order)
    i = 0
    while i < len(key):
        j = i + 1
        while j < len(key) and np.array_equal(key[j], key[i]):
            j += 1
        free = list(range(i, j))
        for k in range(i, j):
            best = max(free, key=lambda f, k=k: _iou(ours[k], theirs[f]))
            free.remove(best)
            out[k] = base[best]
        i = j
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return 1.0 if union == 0 else float(np.logical_and(a, b).sum() / union)


def _compare(case, cpp, conf, mode, preset="", iou=0.7, max_det=300, stats=None) -> None:
    """Assert the C++ results equal the Python reference frame by frame."""
    for stem, (_, kps, depth) in case.frames.items():
        got = cpp[stem]
        pred = case.predict(stem, conf, iou, max_det)
        assert got["letterbox_max_diff"][0] <= 1, stem  # grey levels (docs/cpp_consumer.md)
        if pred.class_map is not None:
            np.testing.assert_array_equal(got["class_map"], pred.class_map, err_msg=stem)
        n = len(pred)
        assert len(got["scores"]) == n, f"{stem}: {len(got['scores'])} vs {n} detections"
        assert np.all(np.diff(got["scores"]) <= 0), stem
        a = _canonical(pred.boxes, pred.scores, pred.classes)
        b = _canonical(got["boxes"], got["scores"], got["classes"])
        if n == max_det:  # a cut among equal scores keeps an unspecified subset of them
            np.testing.assert_array_equal(got["scores"][b], pred.scores[a], err_msg=stem)
            above = pred.scores[a] > pred.scores[a][-1]
            a, b = a[above], b[above]
        np.testing.assert_array_equal(got["classes"][b], pred.classes[a], err_msg=stem)
        np.testing.assert_array_equal(got["scores"][b], pred.scores[a], err_msg=stem)
        np.testing.assert_allclose(got["boxes"][b], pred.boxes[a], rtol=0, atol=1e-3)
        if pred.masks is not None:
            key = np.column_stack([pred.scores, pred.classes, pred.boxes])[a]
            b = _pair_ties(b, pred.masks[a], got["masks"][b] > 0, key)
            ious = [_iou(x, y) for x, y in zip(got["masks"][b] > 0, pred.masks[a], strict=True)]
            assert min(ious, default=1.0) >= 0.999, f"{stem}: mask IoU {min(ious)}"
            if stats is not None:
                stats["pixels"] += int(pred.masks.sum())
                stats["differ"] += int(((got["masks"][b] > 0) != pred.masks[a]).sum())
        ref = _python_dynamic(case, pred, kps, depth, mode, preset)
        np.testing.assert_array_equal(got["dynamic"], ref.mask, err_msg=f"{stem} {mode}")
        np.testing.assert_array_equal(got["keypoint_dynamic"] > 0, ref.dynamic, err_msg=stem)
        assert got["m_th"][0] == (-1.0 if ref.m_th is None else np.float32(ref.m_th)), stem
        used = np.asarray(ref.used_seg, bool)
        order = (b, a) if pred.class_map is None and len(used) else (slice(None), slice(None))
        np.testing.assert_array_equal(got["used_seg"][order[0]] > 0, used[order[1]], err_msg=stem)
        if stats is not None and case.presets[preset].cut_behind_m > 0:
            flat = _python_dynamic(case, pred, kps, None, mode, preset)
            stats["cut"].add(bool((flat.mask != ref.mask).any()))
        if stats is not None and case.presets[preset].rule == "degrade":
            stats["degrade"].add("gave masks up" if ref.dropped else "kept all")
        elif stats is not None:
            start = case.presets[preset].m_th_start
            stats["eq1"].add(
                "no detections" if n == 0 else "gave up" if ref.m_th is None
                else "start" if ref.m_th == start else "raised"
            )  # fmt: skip
            stats["fused"] |= set(used.tolist())
            h, w = pred.image_hw
            x0, y0, x1, y1 = got["boxes"].T
            hits = (x0 == 0).any(), (y0 == 0).any(), (x1 == w).any(), (y1 == h).any()
            stats["borders"] |= {side for side, hit in zip("ltrb", hits, strict=True) if hit}


SLOW = pytest.mark.slow
PARITY = [  # model, mode, score threshold, presets
    ("yolov8n-seg fp32", "fusion", 0.25, ("", "raise", "wide", "papers", "shed")),
    ("yolov8n fp16", "box", 0.25, ("",)),
    ("msnet-t fp32", "fusion", 0.25, ("",)),
    pytest.param("yolov8n-seg fp32", "seg", 0.1, ("",), marks=SLOW),
    pytest.param("msnet-t fp32", "box", 0.25, ("raise",), marks=SLOW),
    pytest.param("yolov8n-seg fp16", "fusion", 0.25, ("", "raise"), marks=SLOW),
    pytest.param("yolov8n-seg-hr fp32", "fusion", 0.25, ("", "raise"), marks=SLOW),
    pytest.param("darknet19-yolov3 fp32", "box", 0.25, ("",), marks=SLOW),
]


@pytest.mark.parametrize(("key", "mode", "conf", "presets"), PARITY)
def test_parity_with_the_python_reference(example, cases, tmp_path, key, mode, conf, presets):
    """Boxes within 1e-3 px (they come out bit-identical), scores and classes equal, mask IoU
    >= 0.999 per instance, identical class maps, dynamic masks, dynamic keypoints and Eq. 1
    thresholds; on the main model every Eq. 1 outcome, the degrading rule giving masks up and
    not, and boxes on every frame border."""
    case = cases(key)
    stats = {"eq1": set(), "degrade": set(), "cut": set(), "pixels": 0, "differ": 0,
             "borders": set(), "fused": set()}  # fmt: skip
    for preset in presets:
        args = ("--mode", mode, "--conf", str(conf), "--preset", preset) if preset else (
            "--mode", mode, "--conf", str(conf))  # fmt: skip
        cpp = _run(example, case, tmp_path / (preset or "default"), *args)
        _compare(case, cpp, conf, mode, preset, stats=stats)
    if (key, mode) == ("yolov8n-seg fp32", "fusion"):  # the main case: every outcome
        assert stats["eq1"] == {"no detections", "gave up", "start", "raised"}, stats["eq1"]
        assert stats["degrade"] == {"gave masks up", "kept all"}, stats["degrade"]
        assert stats["cut"] == {True, False}, "the depth cut changed all masks or none"
        assert stats["borders"] == set("ltrb"), f"boxes touched only {stats['borders']}"
        assert stats["fused"] == {False, True}, "Eq. 4 chose only one of seg mask / box"


@pytest.mark.slow
def test_parity_at_the_detection_cap(example, cases, tmp_path) -> None:
    """Score > 0.001 on a 256 x 256 FP16 input: over 1000 candidates per frame (NMS one class
    at a time, then the `max_det` cut among float16 scores, full of ties)."""
    case = cases("yolov8n-seg 256 fp16")
    args = ("--mode", "seg", "--conf", "0.001", "--iou", "0.9", "--max-det", "300")
    cpp = _run(example, case, tmp_path, *args)
    _compare(case, cpp, 0.001, "seg", iou=0.9, max_det=300)
    assert max(len(r["scores"]) for r in cpp.values()) == 300


def _broken(case: Case, tmp: Path, meta=None, tensors=None, truncate: bool = False) -> Path:
    """A copy of one frame of ``case``'s dumps with its metadata / tensors changed."""
    out = tmp / "dumps"
    out.mkdir()
    stem = next(iter(case.frames))
    shutil.copy(case.dumps / f"{stem}.ppm", out)
    raw = read_raw(case.dumps / f"{stem}.ssraw")
    write_raw(out / f"{stem}.ssraw", {**raw, **(tensors or {})})
    if truncate:
        data = (out / f"{stem}.ssraw").read_bytes()
        (out / f"{stem}.ssraw").write_bytes(data[: len(data) // 2])
    text = (case.dumps / "metadata.json").read_text()
    (out / "metadata.json").write_text(text if meta is None else meta(json.loads(text)))
    return out


def _drop(key):
    return lambda m: json.dumps({k: v for k, v in m.items() if k != key})


def _set(key, value):
    return lambda m: json.dumps({**m, key: value})


BROKEN = {  # what is broken -> the words the one-line error must contain
    "no names": ({"meta": _drop("names")}, "metadata names: missing"),
    "names not a list": ({"meta": _set("names", "person")}, "metadata names: expected an array"),
    "bad t_o": (
        {"meta": lambda m: json.dumps({**m, "slam_masking": {**m["slam_masking"], "t_o": 2}})},
        "metadata slam_masking.t_o: value 2",
    ),
    "unknown family": ({"meta": _set("family", "yolov9")}, "metadata family: 'yolov9'"),
    "bad JSON": ({"meta": lambda m: json.dumps(m)[:-5]}, "JSON (metadata sidecar)"),
    "other imgsz": ({"meta": _set("imgsz", [160, 192])}, "output0: 525 anchors"),
    "output0 rows": (
        {"tensors": {"output0": np.zeros((1, 38, 525), np.float32)}},
        "output0: shape [1, 38, 525], expected [1, 39, A]",
    ),
    "output0 batch": (
        {"tensors": {"output0": np.zeros((2, 39, 525), np.float32)}},
        "output0: shape [2, 39, 525] has batch 2",
    ),
    "output1 size": (
        {"tensors": {"output1": np.zeros((1, 32, 20, 20), np.float32)}},
        "output1: shape [1, 32, 20, 20], expected [1, 32, 40, 40]",
    ),
    "truncated dump": ({"truncate": True}, "truncated raw dump"),
    "descriptor rows": (
        {"tensors": {"descriptors": np.zeros((3, 32), np.uint8)}},
        "descriptors must be uint8 [N, 32] of the keypoints",
    ),
    "camera shape": (
        {
            "tensors": {
                "descriptors": np.zeros((KEYPOINTS, 32), np.uint8),
                "camera": np.ones(3, np.float32),
            }
        },
        "camera must be float32 [4]",
    ),
    "camera values": (
        {
            "tensors": {
                "descriptors": np.zeros((KEYPOINTS, 32), np.uint8),
                "camera": np.array([0, 500, 80, 60], np.float32),
            }
        },
        "camera must be finite (fx, fy, cx, cy) with fx, fy > 0",
    ),
}


@pytest.mark.parametrize("what", list(BROKEN))
def test_malformed_input_gets_a_one_line_error(example, cases, tmp_path, what) -> None:
    change, words = BROKEN[what]
    dumps = _broken(cases("yolov8n-seg fp32"), tmp_path, **change)
    cmd = [str(example), "--meta", str(dumps / "metadata.json"), "--dumps", str(dumps)]
    done = subprocess.run([*cmd, "--out", str(tmp_path / "out")], capture_output=True, text=True)
    assert done.returncode == 2, done.stdout
    assert words in done.stderr and done.stderr.count("\n") == 1, done.stderr
    assert not list(tmp_path.glob("out/*.pgm")), "nothing is written for a bad frame"


@pytest.mark.slow
def test_dump_raw_command_and_example_match_slimseg_dynamic(example, cases, tmp_path) -> None:
    """``slimseg predict --dump-raw`` on a sequence's frames, the example program on the
    dumps (frames read as PPM, the model's own metadata and masking preset, the chain's ORB
    keypoints, descriptors and corners from the dump) and ``slimseg dynamic --no-depth`` on
    the same sequence write identical masks: without depth the motion odds act in both, and
    what needs depth is named once (refused with --strict)."""
    generate(tmp_path / "d", 1, 1, 64, 0, sequences=1, frames=3, seq_size=(160, 120),
             progress=False)  # fmt: skip
    seq = tmp_path / "d" / "sequences" / "seq_000"
    model = str(cases("yolov8n-seg fp32").predictor.path)
    dumps, out = tmp_path / "dumps", tmp_path / "cpp"
    argv = ["predict", "--model", model, "--source", str(seq / "rgb"), "--quiet"]
    assert main([*argv, "--out", str(tmp_path / "pred"), "--dump-raw", str(dumps)]) == 0
    argv = ["dynamic", "--model", model, "--sequence", str(seq), "--quiet", "--no-depth"]
    assert main([*argv, "--out", str(tmp_path / "dyn")]) == 0
    cmd = [str(example), "--meta", str(dumps / "metadata.json"), "--dumps", str(dumps)]
    done = subprocess.run([*cmd, "--out", str(out), "--frames", str(dumps)], capture_output=True)
    assert done.returncode == 0, done.stderr
    _same_masks(seq, out, tmp_path / "dyn")
    # what cannot act without depth is named once, not dropped without a word
    note = "cut_behind_m 0.5, motion_layer_px 100, still_frames 20: settings that cannot act"
    assert done.stderr.decode().count(note) == 1, done.stderr
    strict = subprocess.run([*cmd, "--out", str(tmp_path / "s"), "--strict"], capture_output=True)
    err = strict.stderr.decode().strip().splitlines()
    assert strict.returncode == 2 and len(err) == 1 and note in err[0] and "--strict" in err[0]
    assert not (tmp_path / "s").exists()


# The chain parity test's changes to the shipped preset: the stillness test's window (it acts
# from frame 2 on) and a score threshold that keeps the test model's detections to a few dozen
CHAIN_SETTINGS = {"still_frames": 4, "conf": 0.25}


def test_multi_frame_chain_matches_slimseg_dynamic(example, cases, tmp_path) -> None:
    """The whole preset in C++: ``predict --dump-raw --dump-depth`` on a short synthetic
    sequence (dumps with the chain's ORB keypoints, descriptors and FAST corners, the depth and
    the camera), the example on the dumps and ``slimseg dynamic`` on the sequence (motion
    odds, motion layers, stillness, the degrading rule; ``CHAIN_SETTINGS``): at least 99 %
    of mask pixels equal per frame, and no setting named as unapplied."""
    generate(tmp_path / "d", 0, 0, 64, 131, sequences=1, frames=6, seq_size=(320, 240),
             progress=False, preset="walking_xyz")  # fmt: skip
    seq = tmp_path / "d" / "sequences" / "seq_000"
    model = str(cases("yolov8n-seg fp32").predictor.path)
    dumps = tmp_path / "dumps"
    argv = [
        "predict",
        "--model",
        model,
        "--source",
        str(seq / "rgb"),
        "--quiet",
        "--dump-depth",
        str(seq),
        "--out",
        str(tmp_path / "pred"),
        "--dump-raw",
        str(dumps),
    ]
    assert main(argv) == 0
    meta = json.loads((dumps / "metadata.json").read_text())
    meta["slam_masking"].update(CHAIN_SETTINGS)
    (dumps / "metadata.json").write_text(json.dumps(meta))
    argv = ["dynamic", "--model", model, "--sequence", str(seq), "--quiet",
            "--set", *(f"{k}={v}" for k, v in CHAIN_SETTINGS.items()),
            "--out", str(tmp_path / "dyn")]  # fmt: skip
    assert main(argv) == 0
    cmd = [str(example), "--meta", str(dumps / "metadata.json"), "--dumps", str(dumps)]
    cmd += ["--out", str(tmp_path / "cpp"), "--strict", "--results"]
    done = subprocess.run(cmd, capture_output=True)
    assert done.returncode == 0, done.stderr
    assert b"cannot act" not in done.stderr, done.stderr
    stems = sorted(p.stem for p in (seq / "rgb").glob("*.png"))
    assert len(stems) == 6
    results = [read_raw(tmp_path / "cpp" / f"{stem}.ssres") for stem in stems]
    priors = set(np.float32(meta["mobility"]).tolist())
    assert any(r["still"].any() for r in results), "the stillness test never acted"
    assert any(set(r["mobility"].tolist()) - priors - {0.0} for r in results), "no odds weighed"
    for stem in stems:
        ours = cv2.imread(str(tmp_path / "cpp" / f"{stem}.pgm"), cv2.IMREAD_UNCHANGED)
        theirs = cv2.imread(str(tmp_path / "dyn" / "masks" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        assert (ours == theirs).mean() >= 0.99, stem


def _same_masks(seq: Path, cpp: Path, dynamic: Path) -> None:
    """The example's ``<stem>.pgm`` equal ``slimseg dynamic``'s ``masks/<stem>.png``, every
    frame."""
    stems = sorted(p.stem for p in (seq / "rgb").glob("*.png"))
    assert stems and sorted(p.stem for p in cpp.glob("*.pgm")) == stems
    for stem in stems:
        ours = cv2.imread(str(cpp / f"{stem}.pgm"), cv2.IMREAD_UNCHANGED)
        theirs = cv2.imread(str(dynamic / "masks" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(ours, theirs, err_msg=stem)


def test_dump_raw_needs_an_onnx_model(tmp_path) -> None:
    weights = tmp_path / "w.pt"
    model = build_model("yolov8n-seg", num_classes=1)
    save_weights(weights, model, WeightsInfo(model.spec, ["person"], [1.0]))
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((32, 32, 3), np.uint8))
    argv = ["predict", "--model", str(weights), "--source", str(tmp_path / "a.png")]
    assert main([*argv, "--out", str(tmp_path / "o"), "--dump-raw", str(tmp_path / "d")]) == 2
    assert not (tmp_path / "d").exists()


def test_calibrated_preset_is_the_default(example, cases, tmp_path) -> None:
    """A metadata with a ``calibrated`` preset flat (as slimseg calibrate writes it) is what the
    example applies, silently; without one it says once, after the run, that it used the
    shipped settings."""
    case = cases("yolov8n-seg fp32")
    dumps = tmp_path / "dumps"
    shutil.copytree(case.dumps, dumps)
    cmd = [str(example), "--meta", str(dumps / "metadata.json"), "--dumps", str(dumps)]
    plain = subprocess.run([*cmd, "--out", str(tmp_path / "a")], capture_output=True, text=True)
    assert plain.returncode == 0 and plain.stderr.count("no calibrated masking preset") == 1
    meta = json.loads((dumps / "metadata.json").read_text())
    entry = meta["slam_masking"]
    entry.update(conf=0.99, preset="calibrated")  # nothing scores above it: empty masks
    entry["presets"]["calibrated"] = {k: v for k, v in entry.items() if k not in ("presets",)}
    (dumps / "metadata.json").write_text(json.dumps(meta))
    done = subprocess.run([*cmd, "--out", str(tmp_path / "b")], capture_output=True, text=True)
    assert done.returncode == 0 and "calibrated" not in done.stderr, done.stderr
    masks = sorted((tmp_path / "b").glob("*.pgm"))
    assert masks and all(cv2.imread(str(m), cv2.IMREAD_UNCHANGED).max() == 0 for m in masks)
