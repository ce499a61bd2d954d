"""Bad inputs across the CLI: each ends in one line naming the file or flag, exit 2, no
traceback, and the output location as it was (issue 35).

Every case builds its bad input in its own folder (copies of shared, tiny fixtures), runs the
command in-process from that folder and judges the outcome by one rule (:func:`verdict`):
GOOD = exit 2, exactly one stderr line, naming the file or flag, no traceback, nothing in the
case folder changed; BAD = exit 0 (a silent wrong result) or the case folder changed (a
half-written or extra output); WEAK = anything else (a traceback, several lines, another exit
code, a message that does not name the input).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
import yaml
from onnx import TensorProto, helper

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.deploy.metadata import build_metadata, to_metadata_props
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.models.registry import build_model

NAMES = ["person", "chair"]
MOBILITY = [1.0, 0.0]
IMGSZ = 64


@dataclass(frozen=True)
class Env:
    """The shared inputs: a synthetic sequence (8 frames, 96x64), a dataset with train/val
    splits, random-init weights, and two hand-made ONNX graphs."""

    seq: Path
    data: Path
    weights: Path
    onnx_bad_outputs: Path
    onnx_plain: Path


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Env:
    root = tmp_path_factory.mktemp("bad_inputs")
    generate(root / "d", 2, 1, IMGSZ, 0, sequences=1, frames=8, seq_size=(96, 64), progress=False)
    model = build_model("yolov8n-seg", num_classes=len(NAMES)).eval()
    info = WeightsInfo(model.spec, NAMES, MOBILITY, train_config={"imgsz": IMGSZ})
    weights = save_weights(root / "w.pt", model, info)
    meta = build_metadata(model, NAMES, MOBILITY, (IMGSZ, IMGSZ))
    return Env(
        seq=root / "d" / "sequences" / "seq_000",
        data=root / "d" / "data.yaml",
        weights=weights,
        onnx_bad_outputs=_onnx_output0_only(root / "bad_outputs.onnx", meta),
        onnx_plain=_onnx_output0_only(root / "plain.onnx", None),
    )


def _onnx_output0_only(path: Path, meta: dict | None) -> Path:
    """A graph with the segmenter's ``output0 [1, 4 + nc + 32, A]`` but no ``output1``:
    ``meta`` (a segmenter's, naming both outputs) stamped in, or no metadata at all."""
    rows = 4 + len(NAMES) + 32
    weight = helper.make_tensor(
        "w", TensorProto.FLOAT, [rows, 3, 1, 1], np.full(rows * 3, 0.01, np.float32)
    )
    shape = helper.make_tensor("shape", TensorProto.INT64, [3], [1, rows, IMGSZ * IMGSZ])
    graph = helper.make_graph(
        [
            helper.make_node("Conv", ["images", "w"], ["c"]),
            helper.make_node("Reshape", ["c", "shape"], ["output0"]),
        ],
        "output0_only",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, IMGSZ, IMGSZ])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, rows, IMGSZ * IMGSZ])],
        [weight, shape],
    )
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    proto.ir_version = 8
    for key, value in to_metadata_props(meta or {}).items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))
    return path


# -- building the bad inputs -------------------------------------------------------------


def _seq(env: Env, case: Path) -> Path:
    """A private copy of the sequence (what a case may spoil)."""
    return Path(shutil.copytree(env.seq, case / "seq"))


def _frame(seq: Path, folder: str, k: int) -> Path:
    """The ``k``-th file of ``seq/folder`` in name order."""
    return sorted((seq / folder).iterdir())[k]


def _edit_camera(seq: Path, **changes: object) -> None:
    """Rewrite ``camera.yaml`` with keys renamed (``old=("rename", new)``) or set."""
    cam = yaml.safe_load((seq / "camera.yaml").read_text())
    for key, change in changes.items():
        if isinstance(change, tuple):
            cam[change[1]] = cam.pop(key)
        else:
            cam[key] = change
    (seq / "camera.yaml").write_text(yaml.safe_dump(cam))


def _edit_groundtruth(seq: Path, row: int, values: str) -> None:
    """Replace the ``row``-th pose line of ``groundtruth.txt`` (timestamp kept)."""
    path = seq / "groundtruth.txt"
    lines = path.read_text().splitlines()
    poses = [i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")]
    i = poses[row]
    lines[i] = f"{lines[i].split()[0]} {values}"
    path.write_text("\n".join(lines) + "\n")


def _dyn(seq: Path | str, out: Path | str, *extra: str) -> list[str]:
    return ["dynamic", "--gt-instances", "--sequence", str(seq), "--out", str(out), "--quiet",
            *extra]  # fmt: skip


def _slam(seq: Path, out: Path, *extra: str) -> list[str]:
    return ["slam-eval", "--sequence", str(seq), "--out", str(out), "--engine", "dense",
            "--runs", "1", "--modes", "raw", "--quiet", *extra]  # fmt: skip


def _train(env: Env, out: Path, *extra: str) -> list[str]:
    return ["train", "--model", "yolov8n-seg", "--data", str(env.data), "--out", str(out),
            "--epochs", "1", "--batch", "2", "--imgsz", str(IMGSZ), "--workers", "0",
            "--quiet", *extra]  # fmt: skip


def depth_8bit(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    for p in (seq / "depth").iterdir():
        raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(p), np.clip(raw // 256, 0, 255).astype(np.uint8))
    return _dyn(seq, case / "out", "--mode", "box+depth-ransac"), "depth"


def camera_misspelled(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    _edit_camera(seq, fx=("rename", "fX"), depth_scale=("rename", "depth_scal"))
    return _dyn(seq, case / "out"), "camera.yaml"


def camera_fx_zero(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    _edit_camera(seq, fx=0.0)
    return _dyn(seq, case / "out"), "camera.yaml"


def camera_cy_nan(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    _edit_camera(seq, cy=float("nan"))
    return _dyn(seq, case / "out"), "camera.yaml"


def camera_not_a_number(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    _edit_camera(seq, fx="six hundred")
    return _dyn(seq, case / "out"), "camera.yaml"


def camera_negative_scale(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    _edit_camera(seq, depth_scale=-1.0)
    return _dyn(seq, case / "out"), "camera.yaml"


def corrupt_frame_midway(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    bad = _frame(seq, "rgb", 5)
    bad.write_bytes(bad.read_bytes()[:40])
    return _dyn(seq, case / "out"), bad.name


def depth_wrong_size_midway(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    bad = _frame(seq, "depth", 5)
    cv2.imwrite(str(bad), np.zeros((32, 48), np.uint16))
    return _dyn(seq, case / "out"), bad.name


def dynamic_out_is_a_file(env: Env, case: Path) -> tuple[list[str], str]:
    (case / "taken").write_text("a file\n")
    return _dyn(env.seq, case / "taken"), "taken"


def dynamic_out_under_a_file(env: Env, case: Path) -> tuple[list[str], str]:
    (case / "taken").write_text("a file\n")
    return _dyn(env.seq, case / "taken" / "out"), "taken"


def dynamic_out_read_only(env: Env, case: Path) -> tuple[list[str], str]:
    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders")
    (case / "locked").mkdir()
    (case / "locked").chmod(0o555)
    return _dyn(env.seq, case / "locked" / "out"), "locked"


def gt_dropout_out_of_range(env: Env, case: Path) -> tuple[list[str], str]:
    return _dyn(env.seq, case / "out", "--gt-dropout", "1.5:0"), "--gt-dropout"


def keypoints_not_an_int(env: Env, case: Path) -> tuple[list[str], str]:
    return _dyn(env.seq, case / "out", "--keypoints", "many"), "--keypoints"


def sequence_missing(env: Env, case: Path) -> tuple[list[str], str]:
    return _dyn(case / "nowhere", case / "out"), "nowhere"


def rgb_list_malformed(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    with (seq / "rgb.txt").open("a") as f:
        f.write("12.5\n")
    return _dyn(seq, case / "out"), "rgb.txt"


def rgb_list_missing(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    (seq / "rgb.txt").unlink()
    return _dyn(seq, case / "out"), "rgb.txt"


def dynamic_model_missing(env: Env, case: Path) -> tuple[list[str], str]:
    argv = ["dynamic", "--model", str(case / "gone.onnx"), "--sequence", str(env.seq)]
    return [*argv, "--out", str(case / "out"), "--quiet"], "gone.onnx"


def dynamic_onnx_outputs_mismatch(env: Env, case: Path) -> tuple[list[str], str]:
    argv = ["dynamic", "--model", str(env.onnx_bad_outputs), "--sequence", str(env.seq)]
    return [*argv, "--out", str(case / "out"), "--quiet"], env.onnx_bad_outputs.name


def dynamic_onnx_without_metadata(env: Env, case: Path) -> tuple[list[str], str]:
    argv = ["dynamic", "--model", str(env.onnx_plain), "--sequence", str(env.seq)]
    return [*argv, "--out", str(case / "out"), "--quiet"], env.onnx_plain.name


def _predict(model: Path, source: Path, out: Path, *extra: str) -> list[str]:
    return ["predict", "--model", str(model), "--source", str(source), "--out", str(out),
            "--quiet", *extra]  # fmt: skip


def predict_out_is_a_file(env: Env, case: Path) -> tuple[list[str], str]:
    (case / "taken").write_text("a file\n")
    return _predict(env.weights, _frame(env.seq, "rgb", 0), case / "taken"), "taken"


def predict_track_mixed_sizes(env: Env, case: Path) -> tuple[list[str], str]:
    frames = case / "frames"
    frames.mkdir()
    for k in range(5):
        shutil.copy(_frame(env.seq, "rgb", k), frames / f"f{k}.png")
    rgb = cv2.imread(str(frames / "f3.png"))
    cv2.imwrite(str(frames / "f3.png"), cv2.resize(rgb, (80, 64)))
    return _predict(env.weights, frames, case / "out", "--track"), "f3.png"


def predict_source_missing(env: Env, case: Path) -> tuple[list[str], str]:
    return _predict(env.weights, case / "nothing.png", case / "out"), "nothing.png"


def predict_conf_out_of_range(env: Env, case: Path) -> tuple[list[str], str]:
    return _predict(env.weights, env.seq / "rgb", case / "out", "--conf", "2"), "--conf"


def predict_onnx_outputs_mismatch(env: Env, case: Path) -> tuple[list[str], str]:
    image = _frame(env.seq, "rgb", 0)
    return _predict(env.onnx_bad_outputs, image, case / "out"), env.onnx_bad_outputs.name


def predict_track_one_image(env: Env, case: Path) -> tuple[list[str], str]:
    image = _frame(env.seq, "rgb", 0)
    return _predict(env.weights, image, case / "out", "--track"), image.name


def predict_model_wrong_kind(env: Env, case: Path) -> tuple[list[str], str]:
    (case / "model.txt").write_text("not a model\n")
    return _predict(case / "model.txt", env.seq / "rgb", case / "out"), "model.txt"


def predict_weights_corrupt(env: Env, case: Path) -> tuple[list[str], str]:
    (case / "w.pt").write_bytes(env.weights.read_bytes()[:1000])
    return _predict(case / "w.pt", env.seq / "rgb", case / "out"), "w.pt"


def export_out_is_a_folder(env: Env, case: Path) -> tuple[list[str], str]:
    (case / "exported").mkdir()
    argv = ["export", "--weights", str(env.weights), "--imgsz", str(IMGSZ), "--no-simplify"]
    return [*argv, "--out", str(case / "exported")], "exported"


def export_int8_without_calib(env: Env, case: Path) -> tuple[list[str], str]:
    argv = ["export", "--weights", str(env.weights), "--int8", "--out", str(case / "m.onnx")]
    return argv, "--calib"


def export_weights_corrupt(env: Env, case: Path) -> tuple[list[str], str]:
    (case / "w.pt").write_bytes(b"\x00" * 64)
    return ["export", "--weights", str(case / "w.pt"), "--out", str(case / "m.onnx")], "w.pt"


def groundtruth_nan_position(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    _edit_groundtruth(seq, 3, "nan 0 0 0 0 0 1")
    return _slam(seq, case / "out"), "groundtruth.txt"


def groundtruth_zero_quaternion(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    _edit_groundtruth(seq, 3, "0 0 0 0 0 0 0")
    return _slam(seq, case / "out"), "groundtruth.txt"


def groundtruth_short_line(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    _edit_groundtruth(seq, 3, "0 0 0 0 0 1")
    return _slam(seq, case / "out"), "groundtruth.txt"


def groundtruth_missing(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    (seq / "groundtruth.txt").unlink()
    return _slam(seq, case / "out"), "groundtruth.txt"


def slam_masks_incomplete(env: Env, case: Path) -> tuple[list[str], str]:
    masks = case / "dyn" / "masks"
    masks.mkdir(parents=True)
    for k in range(3):
        shutil.copy(_frame(env.seq, "dynamic", k), masks)
    argv = _slam(env.seq, case / "out", "--masks", str(case / "dyn"))
    argv[argv.index("raw")] = "raw,masks"
    return argv, "masks"


def resume_corrupt_checkpoint(env: Env, case: Path) -> tuple[list[str], str]:
    (case / "run" / "checkpoints").mkdir(parents=True)
    (case / "run" / "checkpoints" / "last.ckpt").write_bytes(b"PK\x03\x04 truncated")
    return _train(env, case / "run", "--resume"), "last.ckpt"


def resume_without_checkpoint(env: Env, case: Path) -> tuple[list[str], str]:
    (case / "run").mkdir()
    return _train(env, case / "run", "--resume"), "last.ckpt"


def train_data_missing(env: Env, case: Path) -> tuple[list[str], str]:
    argv = _train(env, case / "run")
    argv[argv.index(str(env.data))] = str(case / "none.yaml")
    return argv, "none.yaml"


def val_onnx_outputs_mismatch(env: Env, case: Path) -> tuple[list[str], str]:
    argv = ["val", "--weights", str(env.onnx_bad_outputs), "--data", str(env.data)]
    return [*argv, "--imgsz", str(IMGSZ)], env.onnx_bad_outputs.name


CASES: list[Callable[[Env, Path], tuple[list[str], str]]] = [
    depth_8bit,
    camera_misspelled,
    camera_fx_zero,
    camera_cy_nan,
    camera_not_a_number,
    camera_negative_scale,
    corrupt_frame_midway,
    depth_wrong_size_midway,
    dynamic_out_is_a_file,
    dynamic_out_under_a_file,
    dynamic_out_read_only,
    gt_dropout_out_of_range,
    keypoints_not_an_int,
    sequence_missing,
    rgb_list_malformed,
    rgb_list_missing,
    dynamic_model_missing,
    dynamic_onnx_outputs_mismatch,
    dynamic_onnx_without_metadata,
    predict_out_is_a_file,
    predict_track_mixed_sizes,
    predict_source_missing,
    predict_conf_out_of_range,
    predict_onnx_outputs_mismatch,
    predict_track_one_image,
    predict_model_wrong_kind,
    predict_weights_corrupt,
    export_out_is_a_folder,
    export_int8_without_calib,
    export_weights_corrupt,
    groundtruth_nan_position,
    groundtruth_zero_quaternion,
    groundtruth_short_line,
    groundtruth_missing,
    slam_masks_incomplete,
    resume_corrupt_checkpoint,
    resume_without_checkpoint,
    train_data_missing,
    val_onnx_outputs_mismatch,
]


# -- running and judging -----------------------------------------------------------------


def snapshot(folder: Path) -> dict[str, tuple[bool, int, int]]:
    """Every path under ``folder``: (is a folder, size, mtime in ns)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        st = p.lstat()
        out[str(p.relative_to(folder))] = (p.is_dir(), st.st_size, st.st_mtime_ns)
    return out


@dataclass
class Outcome:
    code: int | None
    stderr: str
    escaped: BaseException | None
    changed: list[str]


def run_case(argv: list[str], case: Path, capfd: pytest.CaptureFixture[str]) -> Outcome:
    before = snapshot(case)
    cwd = Path.cwd()
    os.chdir(case)  # a default output path lands in the watched folder
    code, escaped = None, None
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
    except Exception as e:  # what the user would see as a traceback
        escaped = e
    finally:
        os.chdir(cwd)
    captured = capfd.readouterr()
    after = snapshot(case)
    changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
    return Outcome(code, captured.err, escaped, changed)


def verdict(o: Outcome, name: str) -> tuple[str, str]:
    """``(GOOD | WEAK | BAD, why)`` by the rule of the module docstring."""
    lines = [ln for ln in o.stderr.splitlines() if ln.strip()]
    if o.code == 0:
        return "BAD", "exit 0: a silent result"
    if o.changed:
        return "BAD", f"output location changed: {o.changed[:4]}"
    if o.escaped is not None:
        return "WEAK", f"traceback: {type(o.escaped).__name__}: {o.escaped}"
    if "Traceback" in o.stderr:
        return "WEAK", "traceback on stderr"
    if o.code != 2:
        return "WEAK", f"exit {o.code}"
    if len(lines) != 1:
        return "WEAK", f"{len(lines)} lines on stderr: {lines[:3]}"
    if name not in lines[0]:
        return "WEAK", f"does not name {name!r}: {lines[0]}"
    return "GOOD", lines[0]


@pytest.mark.parametrize("build", CASES, ids=[c.__name__ for c in CASES])
def test_bad_input_ends_in_one_line(
    build: Callable[[Env, Path], tuple[list[str], str]],
    env: Env,
    tmp_path: Path,
    capfd: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("SLIMSEG_DEBUG", raising=False)
    argv, name = build(env, tmp_path)
    capfd.readouterr()
    outcome = run_case(argv, tmp_path, capfd)
    kind, why = verdict(outcome, name)
    assert kind == "GOOD", f"{kind}: {why}"
