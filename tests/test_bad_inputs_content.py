"""Hostile content and option ranges (issue 42, classes 3 and 5): a decompression-bomb PNG, a
truncated vocabulary, terminal escapes in data-file text, an ONNX graph with a second input,
a model spec that would allocate without bound, and numeric options out of range.

One-line cases are judged by ``tests/test_bad_inputs.py``'s rule (exit 2, one stderr line
naming the file or flag, no traceback, nothing in the case folder changed). Escape cases
check that no raw control character reaches the terminal and the escaped form does.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import pytest
import yaml
from onnx import TensorProto, helper
from test_bad_inputs import run_case, verdict

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.deploy.metadata import build_metadata, to_metadata_props
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.models.registry import build_model

NAMES = ["person", "dog", "sports ball", "bottle", "chair", "tv"]  # the synthetic data's
MOBILITY = [1.0, 0.75, 0.75, 0.5, 0.25, 0.0]
IMGSZ = 64
ESC = "\x1b[2J\x1b[H"  # clear the screen, cursor home: then a fake verdict could follow
SPEC = Path(__file__).parents[1] / "slimseg" / "configs" / "models" / "yolov8n-seg.yaml"


@dataclass(frozen=True)
class Env:
    """A tiny dataset with a sequence (8 frames, 96x64), random-init weights, a 661-byte-class
    PNG that declares 50000 x 50000 pixels, a vocabulary and an ONNX graph with two inputs."""

    root: Path
    seq: Path
    data: Path
    weights: Path
    bomb: Path
    vocab: Path
    onnx_two_inputs: Path


def png_bomb(path: Path, w: int = 50000, h: int = 50000) -> Path:
    """A valid PNG header declaring ``w x h`` gray pixels, with a few rows of data."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    rows = zlib.compress(b"\x00" * (w + 1) * 4, 9)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", rows)
                     + chunk(b"IEND", b""))  # fmt: skip
    return path


def _vocabulary(path: Path, k: int = 4, levels: int = 2) -> Path:
    """A complete ``k``-ary DBoW2 text tree, ``levels`` deep (BFS order), weights 0.5."""
    lines, level, nid = [f"{k} {levels} 0 0"], [0], 0
    for depth in range(levels):
        nxt = []
        for parent in level:
            for _ in range(k):
                nid += 1
                nxt.append(nid)
                leaf = int(depth == levels - 1)
                lines.append(f"{parent} {leaf} " + " ".join(str((nid * 7 + b) % 256) for b in
                             range(32)) + f" {0.5 if leaf else 0}")  # fmt: skip
        level = nxt
    path.write_text("\n".join(lines) + "\n")
    return path


def _onnx_two_inputs(path: Path, meta: dict) -> Path:
    """The image input plus a second required input (``gain [1]``) multiplied in."""
    rows = 4 + len(NAMES)  # a detector's output0 (its metadata names no output1)
    weight = helper.make_tensor(
        "w", TensorProto.FLOAT, [rows, 3, 1, 1], np.full(rows * 3, 0.01, np.float32)
    )
    shape = helper.make_tensor("shape", TensorProto.INT64, [3], [1, rows, IMGSZ * IMGSZ])
    graph = helper.make_graph(
        [
            helper.make_node("Mul", ["images", "gain"], ["g"]),
            helper.make_node("Conv", ["g", "w"], ["c"]),
            helper.make_node("Reshape", ["c", "shape"], ["output0"]),
        ],
        "two_inputs",
        [
            helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, IMGSZ, IMGSZ]),
            helper.make_tensor_value_info("gain", TensorProto.FLOAT, [1]),
        ],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, rows, IMGSZ * IMGSZ])],
        [weight, shape],
    )
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    proto.ir_version = 8
    for key, value in to_metadata_props(meta).items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))
    return path


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Env:
    root = tmp_path_factory.mktemp("bad_content")
    generate(root / "d", 2, 1, IMGSZ, 0, sequences=1, frames=8, seq_size=(96, 64), progress=False)
    model = build_model("yolov8n-seg", num_classes=len(NAMES)).eval()
    info = WeightsInfo(model.spec, NAMES, MOBILITY, train_config={"imgsz": IMGSZ})
    detector = build_model("yolov8n", num_classes=len(NAMES)).eval()
    meta = build_metadata(detector, NAMES, MOBILITY, (IMGSZ, IMGSZ))
    return Env(
        root=root,
        seq=root / "d" / "sequences" / "seq_000",
        data=root / "d" / "data.yaml",
        weights=save_weights(root / "w.pt", model, info),
        bomb=png_bomb(root / "bomb.png"),
        vocab=_vocabulary(root / "voc.txt"),
        onnx_two_inputs=_onnx_two_inputs(root / "two_inputs.onnx", meta),
    )


def _seq(env: Env, case: Path) -> Path:
    return Path(shutil.copytree(env.seq, case / "seq"))


def _dataset(env: Env, case: Path) -> Path:
    """A private copy of the dataset; returns its data.yaml."""
    shutil.copytree(env.data.parent, case / "d")
    return case / "d" / "data.yaml"


def _first_image(data: Path, split: str = "train") -> Path:
    cfg = yaml.safe_load(data.read_text())
    ann = data.parent / cfg[split]["annotations"] if isinstance(cfg[split], dict) else None
    images = data.parent / (cfg[split]["images"] if ann else cfg[split])
    return sorted(p for p in images.rglob("*.png"))[0]


# -- class 3: hostile content (one line naming the file) ---------------------------------


def predict_png_bomb(env: Env, case: Path) -> tuple[list[str], str]:
    """predict skips an unreadable image and exits 1 (its rule for folders of frames): the
    skip line must say why."""
    src = shutil.copy(env.bomb, case / "bomb.png")
    return ["predict", "--model", str(env.weights), "--source", str(src), "--out",
            str(case / "out"), "--quiet"], "bomb.png: declares 50000x50000"  # fmt: skip


def dynamic_png_bomb_frame(env: Env, case: Path) -> tuple[list[str], str]:
    seq = _seq(env, case)
    frame = sorted((seq / "rgb").iterdir())[3]
    shutil.copy(env.bomb, frame)
    return ["dynamic", "--gt-instances", "--sequence", str(seq), "--out", str(case / "out"),
            "--quiet"], f"{frame.name}: declares 50000x50000"  # fmt: skip


def slam_vocab_png_bomb(env: Env, case: Path) -> tuple[list[str], str]:
    src = shutil.copy(env.bomb, case / "bomb.png")
    return ["slam", "vocab", "--images", str(src), "--out", str(case / "voc.txt")], "declares"


def data_show_png_bomb(env: Env, case: Path) -> tuple[list[str], str]:
    data = _dataset(env, case)
    image = _first_image(data)
    shutil.copy(env.bomb, image)
    return ["data", "show", "--data", str(data), "--imgsz", "64", "--count", "2", "--out",
            str(case / "show.png")], f"{image.name}: declares 50000x50000"  # fmt: skip


def slam_eval_png_bomb_frame(env: Env, case: Path) -> tuple[list[str], str]:
    pytest.importorskip("evo", reason="the [slam] extra")
    seq = _seq(env, case)
    frame = sorted((seq / "rgb").iterdir())[5]
    shutil.copy(env.bomb, frame)
    return ["slam-eval", "--sequence", str(seq), "--out", str(case / "out"), "--engine", "dense",
            "--runs", "1", "--modes", "raw", "--quiet"], f"{frame.name}: declares"  # fmt: skip


def pixel_cap_env_not_a_number(env: Env, case: Path) -> tuple[list[str], str]:
    """The cap's variable set to a non-number (by the test, see :data:`CASE_ENV`)."""
    return ["predict", "--model", str(env.weights), "--source", str(env.seq / "rgb"), "--out",
            str(case / "out"), "--quiet"], "SLIMSEG_MAX_IMAGE_PIXELS"  # fmt: skip


def slam_eval_truncated_vocabulary(env: Env, case: Path) -> tuple[list[str], str]:
    pytest.importorskip("evo", reason="the [slam] extra")
    pytest.importorskip("pyorbslam3", reason="the [slam] extra")
    lines = env.vocab.read_text().splitlines()
    cut = case / "ORBvoc_cut.txt"
    cut.write_text("\n".join(lines[: len(lines) // 2]) + "\n")  # cut at a line end
    return ["slam-eval", "--sequence", str(env.seq), "--out", str(case / "out"), "--vocab",
            str(cut), "--runs", "1", "--modes", "raw", "--quiet"], "ORBvoc_cut.txt"  # fmt: skip


def slam_eval_vocabulary_nan_weight(env: Env, case: Path) -> tuple[list[str], str]:
    pytest.importorskip("evo", reason="the [slam] extra")
    pytest.importorskip("pyorbslam3", reason="the [slam] extra")
    lines = env.vocab.read_text().splitlines()
    lines[-1] = lines[-1].rsplit(" ", 1)[0] + " nan"
    bad = case / "voc_nan.txt"
    bad.write_text("\n".join(lines) + "\n")
    return ["slam-eval", "--sequence", str(env.seq), "--out", str(case / "out"), "--vocab",
            str(bad), "--runs", "1", "--modes", "raw", "--quiet"], "voc_nan.txt"  # fmt: skip


# -- class 5: option ranges and model shapes (one line naming the flag or file) ----------


def _opt(*argv: str) -> Callable[[Env, Path], tuple[list[str], str]]:
    """A case whose argv is fixed (``{weights}``, ``{data}``, ``{seq}``, ``{out}`` filled in);
    the flag named is the last one before the bad value."""
    flag = [a for a in argv if a.startswith("--")][-1]

    def build(env: Env, case: Path) -> tuple[list[str], str]:
        subs = {"{weights}": str(env.weights), "{data}": str(env.data), "{seq}": str(env.seq),
                "{out}": str(case / "out")}  # fmt: skip
        return [subs.get(a, a) for a in argv], flag

    name = "_".join(a.lstrip("-").replace("-", "_") for a in argv if not a.startswith("{"))
    build.__name__ = "".join(c if c.isalnum() else "_" for c in name)
    return build


def _spec_case(width: str) -> Callable[[Env, Path], tuple[list[str], str]]:
    def build(env: Env, case: Path) -> tuple[list[str], str]:
        spec = case / "wide.yaml"
        spec.write_text(SPEC.read_text().replace("width: 0.25", f"width: {width}"))
        return ["info", "--model", str(spec), "--imgsz", "64"], "wide.yaml"

    build.__name__ = f"info_spec_width_{width.replace('-', 'minus_').replace('.', '_')}"
    return build


def predict_onnx_second_input(env: Env, case: Path) -> tuple[list[str], str]:
    return ["predict", "--model", str(env.onnx_two_inputs), "--source",
            str(sorted((env.seq / "rgb").iterdir())[0]), "--out", str(case / "out"),
            "--quiet"], "two_inputs.onnx: the graph takes 2 inputs"  # fmt: skip


def dynamic_onnx_second_input(env: Env, case: Path) -> tuple[list[str], str]:
    return ["dynamic", "--model", str(env.onnx_two_inputs), "--sequence", str(env.seq), "--out",
            str(case / "out"), "--quiet"], "two_inputs.onnx"  # fmt: skip


PRED = ("predict", "--model", "{weights}", "--source", "{seq}", "--out", "{out}")
CASES_C = [
    # the examples
    _opt("val", "--weights", "{weights}", "--data", "{data}", "--conf", "nan"),
    _opt("bench", "--model", "yolov8n-seg", "--runs", "0"),
    _opt("bench", "--model", "yolov8n-seg", "--imgsz", "33"),
    _opt("data", "show", "--data", "{data}", "--out", "{out}", "--count", "0"),
    _opt("data", "show", "--data", "{data}", "--out", "{out}", "--columns", "-3"),
    _opt("dynamic", "--gt-instances", "--sequence", "{seq}", "--out", "{out}", "--keypoints", "-5"),
    _spec_case("-0.25"),
    _spec_case("64"),
    predict_onnx_second_input,
    # other commands and options
    dynamic_onnx_second_input,
    _opt(*PRED, "--iou", "1.5"),
    _opt(*PRED, "--conf", "inf"),
    _opt(*PRED, "--max-det", "0"),
    _opt("train", "--model", "yolov8n-seg", "--data", "{data}", "--out", "{out}", "--epochs", "0"),
    _opt("train", "--model", "yolov8n-seg", "--data", "{data}", "--out", "{out}", "--lr0", "nan"),
    _opt("export", "--weights", "{weights}", "--out", "{out}", "--imgsz", "100"),
    _opt("slam", "vocab", "--images", "x/*.png", "--out", "{out}", "--k", "1"),
    _opt("info", "--model", "yolov8n-seg", "--imgsz", "33"),
    _opt("slam-eval", "--sequence", "{seq}", "--out", "{out}", "--speed", "0"),
    _opt("data", "synth", "--out", "{out}", "--frames", "-1"),
    _opt("dynamic", "--gt-instances", "--sequence", "{seq}", "--out", "{out}", "--threads", "-1"),
]
CASES_B = [
    predict_png_bomb,
    dynamic_png_bomb_frame,
    slam_vocab_png_bomb,
    data_show_png_bomb,
    slam_eval_png_bomb_frame,
    pixel_cap_env_not_a_number,
    slam_eval_truncated_vocabulary,
    slam_eval_vocabulary_nan_weight,
]
CASE_ENV = {"pixel_cap_env_not_a_number": {"SLIMSEG_MAX_IMAGE_PIXELS": "lots"}}
CASE_EXIT = {"predict_png_bomb": 1}  # predict skips unreadable frames, then exits 1
CASES = CASES_B + CASES_C


@pytest.mark.parametrize("build", CASES, ids=[c.__name__ for c in CASES])
def test_bad_content_and_options_end_in_one_line(
    build: Callable[[Env, Path], tuple[list[str], str]],
    env: Env,
    tmp_path: Path,
    capfd: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("SLIMSEG_DEBUG", raising=False)
    for key, value in CASE_ENV.get(build.__name__, {}).items():
        monkeypatch.setenv(key, value)
    argv, name = build(env, tmp_path)
    capfd.readouterr()
    outcome = run_case(argv, tmp_path, capfd)
    if outcome.code == CASE_EXIT.get(build.__name__):
        outcome.code = 2  # that command's documented code; the one-line rule is the same
    kind, why = verdict(outcome, name)
    assert kind == "GOOD", f"{kind}: {why}"


# -- class 3: text from data files printed escaped ---------------------------------------


def _escaped_run(argv: list[str], capfd: pytest.CaptureFixture[str]) -> str:
    """Run ``argv`` in-process; everything it printed (stdout and stderr)."""
    capfd.readouterr()
    with contextlib.suppress(SystemExit):
        main(argv)
    printed = capfd.readouterr()
    return printed.out + printed.err


def test_data_check_prints_file_names_escaped(env: Env, tmp_path: Path, capfd) -> None:
    data = _dataset(env, tmp_path)
    cfg = yaml.safe_load(data.read_text())
    ann_path = data.parent / cfg["val"]["annotations"]
    ann = json.loads(ann_path.read_text())
    ann["images"][0]["file_name"] = f"{ESC}OK: 0 errors\r.png"
    ann_path.write_text(json.dumps(ann))
    capfd.readouterr()
    code = main(["data", "check", str(data), "--split", "val", "--quiet"])
    printed = capfd.readouterr()
    text = printed.out + printed.err
    assert code == 1 and "\x1b" not in text and "\r" not in text
    assert "\\x1b[2J\\x1b[HOK: 0 errors\\r.png" in text  # shown, not obeyed


def test_error_line_names_a_hostile_path_escaped(env: Env, tmp_path: Path, capfd) -> None:
    """slam-eval on a sequence whose rgb.txt lists a file named with escapes."""
    seq = _seq(env, tmp_path)
    rgb = seq / "rgb.txt"
    lines = rgb.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln and not ln.startswith("#"))
    stamp = lines[i].split()[0]
    lines[i] = f"{stamp} rgb/{ESC}fake.png"
    rgb.write_text("\n".join(lines) + "\n")
    argv = ["dynamic", "--gt-instances", "--sequence", str(seq), "--out", str(tmp_path / "o"),
            "--quiet"]  # fmt: skip
    printed = _escaped_run(argv, capfd)
    assert "\x1b" not in printed and "\\x1b[2J\\x1b[Hfake.png" in printed, printed


def test_error_line_escapes_a_path_from_data_yaml(env: Env, tmp_path: Path, capfd) -> None:
    """data show on a data.yaml whose annotations path holds escapes (and does not exist)."""
    data = _dataset(env, tmp_path)
    cfg = yaml.safe_load(data.read_text())
    cfg["train"]["annotations"] = f"train/{ESC}OK.json"
    data.write_text(yaml.safe_dump(cfg))
    argv = ["data", "show", "--data", str(data), "--out", str(tmp_path / "s.png")]
    printed = _escaped_run(argv, capfd)
    assert "\x1b" not in printed and "train/\\x1b[2J\\x1b[HOK.json" in printed, printed


def test_lightning_device_banners_are_held_while_the_trainer_is_built() -> None:
    """Caught at Lightning's own logger (set up here: other tests of the suite may have
    configured or disabled Lightning's loggers), so the test does not depend on test order."""
    import logging

    import lightning as L

    from slimseg.engine.banners import BANNER_LOGGERS, quiet_device_banners

    lines: list[str] = []

    class Catch(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            lines.append(record.getMessage())

    def build() -> list[str]:
        lines.clear()
        L.Trainer(accelerator="cpu", devices=1, logger=False, enable_checkpointing=False,
                  enable_progress_bar=False, enable_model_summary=False)  # fmt: skip
        return list(lines)

    lg = logging.getLogger(BANNER_LOGGERS[0])
    catch, state = Catch(), (lg.level, lg.disabled)
    lg.addHandler(catch)
    lg.setLevel(logging.INFO)
    lg.disabled = False
    try:
        assert any("GPU available" in t for t in build())  # Lightning's own, outside the block
        with quiet_device_banners():
            held = build()
        assert not any("GPU available" in t or "TPU available" in t for t in held), held
        assert all(not logging.getLogger(name).filters for name in BANNER_LOGGERS)
        assert any("GPU available" in t for t in build())  # the loggers are as they were
    finally:
        lg.removeHandler(catch)
        lg.setLevel(state[0])
        lg.disabled = state[1]
