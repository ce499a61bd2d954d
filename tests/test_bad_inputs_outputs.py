"""A command writes only what it owns, reads only inside the roots it was given, and leaves
no half-written output (issue 42, classes 1, 2 and 4; :mod:`slimseg.utils.outputs`).

Each case runs the CLI in-process on tiny shared fixtures and asserts the outcome: a refusal
is exit 2 with one stderr line naming the flag or file, and the user's files byte for byte as
they were.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.data.synth.categories import MOBILITY, NAMES
from slimseg.deploy.onnx_export import export_onnx
from slimseg.errors import SlimsegError
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.models.registry import build_model
from slimseg.utils.atomic import staged_dir
from slimseg.utils.outputs import MANIFEST, unique_stems

IMGSZ = 64
USER = b"the user's own file, never to be lost"


@dataclass(frozen=True)
class Env:
    """A synthetic dataset (2 train + 1 val images, one 8-frame 96x64 sequence), random-init
    weights and their ONNX export, all at 64 px."""

    root: Path
    data: Path
    seq: Path
    weights: Path
    onnx: Path


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Env:
    root = tmp_path_factory.mktemp("outputs")
    generate(root / "d", 2, 1, IMGSZ, 0, sequences=1, frames=8, seq_size=(96, 64), progress=False)
    model = build_model("yolov8n-seg", num_classes=len(NAMES)).eval()
    info = WeightsInfo(model.spec, list(NAMES), list(MOBILITY), train_config={"imgsz": IMGSZ})
    weights = save_weights(root / "w.pt", model, info)
    onnx = root / "m.onnx"
    export_onnx(model, onnx, (IMGSZ, IMGSZ), list(NAMES), list(MOBILITY), simplify=False)
    return Env(root, root / "d" / "data.yaml", root / "d" / "sequences" / "seq_000", weights, onnx)


def run(argv: list[str], capfd: pytest.CaptureFixture[str], cwd: Path | None = None):
    """``(exit code, stderr lines, stdout)`` of ``slimseg argv`` run in-process."""
    capfd.readouterr()
    before = Path.cwd()
    if cwd is not None:
        os.chdir(cwd)
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
    finally:
        os.chdir(before)
    captured = capfd.readouterr()
    return code, [ln for ln in captured.err.splitlines() if ln.strip()], captured.out


def refused(argv: list[str], capfd: pytest.CaptureFixture[str], *names: str) -> str:
    """Assert one stderr line, exit 2, naming each of ``names``; returns the line."""
    code, err, _ = run(argv, capfd)
    assert code == 2 and len(err) == 1, (code, err)
    for name in names:
        assert name in err[0], err[0]
    return err[0]


def tree(folder: Path) -> dict[str, bytes | None]:
    """Every path under ``folder`` with its bytes (``None``: a folder)."""
    return {
        str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes())
        for p in sorted(folder.rglob("*"))
    }


def user_folder(path: Path, *names: str) -> dict[str, bytes | None]:
    """A user's folder holding ``names`` (``x/`` a subfolder with a file); its tree."""
    path.mkdir(parents=True, exist_ok=True)
    for name in names:
        if name.endswith("/"):
            (path / name).mkdir()
            (path / name / "keep.txt").write_bytes(USER)
        else:
            (path / name).write_bytes(USER)
    return tree(path)


def frames_folder(path: Path, names: list[str]) -> Path:
    """Images named ``names`` (PNG/JPEG by suffix), 120x160 blocks of random colours (ORB
    keypoints at the corners)."""
    path.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(len(names))
    for name in names:  # blocky noise: ORB finds keypoints in it
        blocks = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
        big = cv2.resize(blocks, (160, 120), interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(path / name), big)
    return path


def _predict(env: Env, source: Path, out: Path, *extra: str) -> list[str]:
    return [
        "predict",
        "--model",
        str(env.onnx),
        "--source",
        str(source),
        "--out",
        str(out),
        "--quiet",
        *extra,
    ]


def _dyn(env: Env, seq: Path, out: Path) -> list[str]:
    return ["dynamic", "--gt-instances", "--sequence", str(seq), "--out", str(out), "--quiet"]


def _slam(seq: Path, out: Path) -> list[str]:
    return [
        "slam-eval",
        "--sequence",
        str(seq),
        "--out",
        str(out),
        "--engine",
        "dense",
        "--runs",
        "1",
        "--modes",
        "raw",
        "--quiet",
    ]


def _sweep(tmp: Path, env: Env, name: str = "tiny") -> Path:
    cfg = tmp / "sweep.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "name": name,
                "variants": ["yolov8n-seg"],
                "data": str(env.data),
                "train": {"recipe": "cpu-demo", "epochs": 1},
            }
        )
    )
    return cfg


# -- class 1: a command writes only what it owns --------------------------------------------


def test_slam_eval_raw_keeps_the_users_masks_and_notes(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "myproject"
    before = user_folder(out, "masks/", "trajectories/")
    refused(_slam(env.seq, out), capfd, "--out", "masks", "did not write")
    assert tree(out) == before


def test_dynamic_keeps_a_users_masks(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "work"
    before = user_folder(out, "masks/")
    refused(_dyn(env, env.seq, out), capfd, "--out", "masks")
    assert tree(out) == before


def test_dynamic_reruns_into_its_own_folder_and_refuses_the_sequence(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "dyn"
    assert run(_dyn(env, env.seq, out), capfd)[0] == 0
    assert (out / MANIFEST).is_file() and (out / "masks").is_dir()
    first = sorted(p.name for p in out.iterdir())
    assert run(_dyn(env, env.seq, out), capfd)[0] == 0  # its own folder: replaced whole
    assert sorted(p.name for p in out.iterdir()) == first
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no stage left
    seq = Path(shutil.copytree(env.seq, tmp_path / "seq"))
    before = tree(seq)
    refused(_dyn(env, seq, seq), capfd, "--out", "would overwrite the input --sequence")
    assert tree(seq) == before


def test_ablate_keeps_a_users_results(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "mine"
    before = user_folder(out, "results.csv", "results.md")
    argv = ["ablate", "--config", str(_sweep(tmp_path, env)), "--out", str(out), "--quiet"]
    refused(argv, capfd, "--out", "results.csv")
    assert tree(out) == before


def test_predict_source_as_out_is_refused(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    frames = frames_folder(tmp_path / "frames", ["a.png", "b.png"])
    (frames / "a.json").write_bytes(USER)
    before = tree(frames)
    refused(_predict(env, frames, frames), capfd, "would overwrite the input --source")
    refused(
        _predict(env, frames, tmp_path / "o", "--dump-raw", str(frames)),
        capfd,
        "--dump-raw",
        "--source",
    )
    assert tree(frames) == before
    assert not (tmp_path / "o").exists()


def test_predict_names_never_collide(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    frames = frames_folder(tmp_path / "frames", ["a.png", "a.jpg", "a_png.png"])
    out = tmp_path / "out"
    assert run(_predict(env, frames, out), capfd)[0] == 0
    sources = sorted(json.loads(p.read_text())["image"] for p in out.glob("[!.]*.json"))
    assert sources == sorted(str(frames / n) for n in ("a.png", "a.jpg", "a_png.png"))
    assert unique_stems(["a", "a", "a_png"], [".png", ".jpg", ".png"]) == [
        "a_png_2",
        "a_jpg",
        "a_png",
    ]


def test_export_onto_its_weights_or_a_users_json_is_refused(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    best = Path(shutil.copy(env.weights, tmp_path / "best.pt"))
    weights_bytes = best.read_bytes()
    argv = ["export", "--weights", str(best), "--imgsz", str(IMGSZ), "--no-simplify"]
    refused([*argv, "--out", str(best)], capfd, "--out", "--weights")
    assert best.read_bytes() == weights_bytes
    train = tmp_path / "train"
    before = user_folder(train, "annotations.json")
    refused([*argv, "--out", str(train / "annotations.onnx")], capfd, "annotations.json")
    before_model = user_folder(tmp_path / "m", "model.onnx")  # not an export of slimseg's
    refused([*argv, "--out", str(tmp_path / "m" / "model.onnx")], capfd, "model.onnx")
    assert tree(train) == before and tree(tmp_path / "m") == before_model


def test_val_save_json_onto_ground_truth_or_yaml_is_refused(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    data = Path(shutil.copytree(env.data.parent, tmp_path / "d"))
    gt = data / "val" / "annotations.json"
    before = tree(data)
    argv = [
        "val",
        "--weights",
        str(env.weights),
        "--data",
        str(data / "data.yaml"),
        "--imgsz",
        str(IMGSZ),
        "--workers",
        "0",
        "--json",
    ]
    refused([*argv, "--save-json", str(gt)], capfd, "--save-json", "val split's annotations")
    refused([*argv, "--save-json", str(data / "data.yaml")], capfd, "--save-json", "--data")
    (data / "notes.json").write_text('{"mine": 1}')
    refused([*argv, "--save-json", str(data / "notes.json")], capfd, "notes.json")
    assert tree(data) == before | {"notes.json": b'{"mine": 1}'}


def test_slam_vocab_onto_an_input_frame_is_refused(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    frames = frames_folder(tmp_path / "f", ["1.png", "2.png", "3.png"])
    before = tree(frames)
    argv = ["slam", "vocab", "--images", str(frames / "*.png"), "--k", "2", "--levels", "1"]
    refused([*argv, "--max-images", "1", "--out", str(frames / "3.png")], capfd, "--images")
    (tmp_path / "notes.txt").write_bytes(USER)
    refused([*argv, "--out", str(tmp_path / "notes.txt")], capfd, "notes.txt")
    assert tree(frames) == before and (tmp_path / "notes.txt").read_bytes() == USER


def test_synth_overwrite_deletes_only_a_synthetic_dataset(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    mine = tmp_path / "mine"
    before = user_folder(mine, "train/", "thesis.tex")
    argv = ["data", "synth", "--train", "1", "--val", "1", "--imgsz", "64", "--quiet"]
    refused([*argv, "--out", str(mine), "--overwrite"], capfd, "--out", "thesis.tex")
    assert tree(mine) == before
    ours = tmp_path / "ours"
    assert run([*argv, "--out", str(ours)], capfd)[0] == 0
    assert run([*argv, "--out", str(ours), "--overwrite", "--seed", "3"], capfd)[0] == 0
    assert "--seed 3" in (ours / "data.yaml").read_text()


def test_staged_dir_swaps_the_whole_folder(tmp_path: Path, monkeypatch) -> None:
    out = tmp_path / "out"
    for exchange in (True, False):  # the kernel's atomic exchange, and the two renames
        if not exchange:
            monkeypatch.setattr("slimseg.utils.atomic._exchange", lambda a, b: False)
        with staged_dir(out, command="t") as stage:
            (stage / "old.txt").write_text("old")
        inode = out.stat().st_ino
        with staged_dir(out, command="t") as stage:
            (stage / "new.txt").write_text("new")
        assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "new.txt"]
        assert out.stat().st_ino != inode  # a new folder took its place, not a merge
        assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_file_dropped_in_while_a_command_runs_is_kept(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with staged_dir(out, command="t") as stage:
        (stage / "a.txt").write_text("run 1")
    with staged_dir(out, command="t") as stage:
        (stage / "a.txt").write_text("run 2")
        (out / "notes.txt").write_bytes(USER)  # the user, meanwhile
    assert (out / "notes.txt").read_bytes() == USER and (out / "a.txt").read_text() == "run 2"
    assert "notes.txt" not in json.loads((out / MANIFEST).read_text())["entries"]
    (out / "notes.txt").unlink()
    with pytest.raises(SlimsegError, match=r"b\.txt appeared"), staged_dir(out) as stage:
        (stage / "b.txt").write_text("run 3")
        (out / "b.txt").write_bytes(USER)  # the same name the command writes
    assert (out / "b.txt").read_bytes() == USER and (out / "a.txt").read_text() == "run 2"


# -- class 1: no command deletes or overwrites a user's file in its --out -------------------


def _user_file_cases(env: Env, tmp: Path) -> dict[str, tuple[list[str], Path]]:
    """``{command: (argv, the user's file)}``; the file sits in (or at) the command's output."""
    frames = frames_folder(tmp / "frames", ["a.png"])
    seq = Path(shutil.copytree(env.seq, tmp / "seq"))
    (tmp / "classes.yaml").write_text("classes: [{name: person, coco_id: 1, mobility: 1.0}]\n")
    out = tmp / "out"
    syn = ["data", "synth", "--train", "1", "--val", "1", "--imgsz", "64", "--quiet"]
    val = [
        "val",
        "--weights",
        str(env.weights),
        "--data",
        str(env.data),
        "--imgsz",
        "64",
        "--workers",
        "0",
        "--json",
    ]
    vocab = ["slam", "vocab", "--images", str(seq / "rgb" / "*.png"), "--k", "2", "--levels", "1"]
    export = ["export", "--weights", str(env.weights), "--imgsz", "64", "--no-simplify"]
    return {
        "predict": (_predict(env, frames, out / "p"), out / "p" / "notes.txt"),
        "predict --track": (_predict(env, frames, out / "t", "--track"), out / "t" / "notes.txt"),
        "predict --dump-raw": (
            _predict(env, frames, out / "p2", "--dump-raw", str(out / "r")),
            out / "r" / "metadata.json",
        ),
        "dynamic": (_dyn(env, seq, out / "d"), out / "d" / "frames.csv"),
        "slam-eval": (_slam(seq, out / "s"), out / "s" / "results.md"),
        "data synth": ([*syn, "--out", str(out / "y"), "--overwrite"], out / "y" / "data.yaml"),
        "ablate": (
            ["ablate", "--config", str(_sweep(tmp, env)), "--out", str(out / "a")],
            out / "a" / "summary.csv",
        ),
        "export": ([*export, "--out", str(out / "e" / "m.onnx")], out / "e" / "m.json"),
        "val --save-json": ([*val, "--save-json", str(out / "v.json")], out / "v.json"),
        "slam vocab": ([*vocab, "--out", str(out / "voc.txt")], out / "voc.txt"),
        "slam-eval --sweep": (
            [
                "slam-eval",
                "--sequence",
                str(seq),
                "--out",
                str(out / "w"),
                "--engine",
                "dense",
                "--runs",
                "1",
                "--gt-instances",
                "--sweep",
                "dilation=0,2",
                "--quiet",
            ],
            out / "w" / "sweep.md",
        ),
        "data coco-subset": (
            [
                "data",
                "coco-subset",
                "--ann",
                str(env.data.parent / "val" / "annotations.json"),
                "--classes",
                str(tmp / "classes.yaml"),
                "--out",
                str(out / "c"),
            ],
            out / "c" / "annotations.json",
        ),
    }


def test_no_command_deletes_or_overwrites_a_user_file_in_its_out(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    cases = _user_file_cases(env, tmp_path)
    lost = {}
    for command, (argv, user_file) in cases.items():
        user_file.parent.mkdir(parents=True, exist_ok=True)
        user_file.write_bytes(USER)
        code, err, _ = run(argv, capfd)
        if not user_file.is_file() or user_file.read_bytes() != USER:
            lost[command] = (code, err[-1:] if err else "")
        elif code != 2 or len(err) != 1:
            lost[command] = ("kept, but not one refusal line", code, err[-2:])
    assert not lost, "\n".join(f"{command}: {why}" for command, why in lost.items())


# -- class 2: paths read from data files stay inside their root -----------------------------


@pytest.mark.parametrize("name", ["../../../escaped", "ABSOLUTE", "a/b"])  # issue 42
def test_sweep_name_is_checked_like_arm_names(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str], name: str
) -> None:
    work = tmp_path / "work"
    work.mkdir()
    name = str(tmp_path / "abs-sweep") if name == "ABSOLUTE" else name
    argv = ["ablate", "--config", str(_sweep(work, env, name)), "--quiet"]
    code, err, _ = run(argv, capfd, cwd=work)  # --out runs/ablate/<name>: tmp_path/escaped
    assert code == 2 and len(err) == 1 and "'name' must be a folder-safe" in err[0], err
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["sweep.yaml", "work"]


def _sequence_with(env: Env, tmp: Path, list_name: str, k: int, path: str) -> Path:
    """A copy of the sequence whose ``list_name`` names ``path`` on its ``k``-th entry."""
    seq = Path(shutil.copytree(env.seq, tmp / "seq"))
    lines = (seq / list_name).read_text().splitlines()
    rows = [i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")]
    lines[rows[k]] = f"{lines[rows[k]].split()[0]} {path}"
    (seq / list_name).write_text("\n".join(lines) + "\n")
    return seq


def test_rgb_list_path_outside_the_sequence_is_refused_unless_allowed(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    outside = tmp_path / "outside.png"
    shutil.copy(sorted((env.seq / "rgb").iterdir())[0], outside)
    seq = _sequence_with(env, tmp_path, "rgb.txt", 0, "../outside.png")
    refused(
        _dyn(env, seq, tmp_path / "o"), capfd, "rgb.txt:", "../outside.png", "--allow-outside-root"
    )
    assert not (tmp_path / "o").exists()
    code, *_ = run(["--allow-outside-root", *_dyn(env, seq, tmp_path / "o")], capfd)
    assert code == 0 and (tmp_path / "o" / "masks").is_dir()  # the user said so


def test_depth_list_absolute_path_is_refused_by_slam_eval(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    depth = sorted((env.seq / "depth").iterdir())[1]
    seq = _sequence_with(env, tmp_path, "depth.txt", 1, str(depth))
    refused(_slam(seq, tmp_path / "o"), capfd, "depth.txt:", "outside")


def test_file_name_outside_the_images_folder_is_not_read(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    data = Path(shutil.copytree(env.data.parent, tmp_path / "d"))
    ann = data / "train" / "annotations.json"
    coco = json.loads(ann.read_text())
    coco["images"][0]["file_name"] = "../../../../etc/hostname"
    coco["images"][1]["file_name"] = str(data / "val" / "images" / "000000.png")
    ann.write_text(json.dumps(coco))
    code, _, out = run(["data", "check", str(data / "data.yaml")], capfd)
    assert code != 0 and "path_outside_root" in out, out
    assert "hostname" in out and "000000.png" in out  # both named, neither read


def test_data_yaml_split_outside_its_root_is_refused(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    data = Path(shutil.copytree(env.data.parent, tmp_path / "d"))
    cfg = yaml.safe_load((data / "data.yaml").read_text())
    shutil.copytree(data / "val" / "images", tmp_path / "elsewhere" / "images")  # readable
    cfg["val"]["images"] = "../elsewhere/images"
    (data / "data.yaml").write_text(yaml.safe_dump(cfg))
    argv = [
        "val",
        "--weights",
        str(env.weights),
        "--data",
        str(data / "data.yaml"),
        "--imgsz",
        "64",
        "--workers",
        "0",
    ]
    refused(argv, capfd, "val.images", "outside", "--allow-outside-root")


def test_vocab_symlink_loop_counts_each_frame_once(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    from slimseg.cli.slam import expand_images

    frames = frames_folder(tmp_path / "f", ["1.png", "2.png"])
    (frames / "loop").symlink_to(frames, target_is_directory=True)
    paths = expand_images([str(frames / "**" / "*.png")], 100)
    assert len(paths) == 2


# -- class 4: outputs never written in place ------------------------------------------------


def test_interrupted_dump_raw_leaves_no_half_dump(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch
) -> None:
    from slimseg.deploy.predictor import Predictor

    frames = frames_folder(tmp_path / "frames", ["1.png", "2.png", "3.png"])
    dump, out = tmp_path / "dump", tmp_path / "out"
    argv = _predict(env, frames, out, "--dump-raw", str(dump))
    real, calls = Predictor.predict, []

    def stop_at_frame_two(self, *a, **k):
        calls.append(1)
        if len(calls) % 3 == 2:  # the second frame of a run
            raise KeyboardInterrupt
        return real(self, *a, **k)

    with monkeypatch.context() as m:
        m.setattr(Predictor, "predict", stop_at_frame_two)
        assert run(argv, capfd)[0] == 130  # Ctrl-C at frame 2 of 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames"]  # no half dump, no out
    assert run(argv, capfd)[0] == 0
    assert len(list(dump.glob("*.ssraw"))) == 3 and (dump / "metadata.json").is_file()
    before_dump, before_out = tree(dump), tree(out)
    calls.clear()
    monkeypatch.setattr(Predictor, "predict", stop_at_frame_two)
    assert run([*argv, "--keypoints", "50"], capfd)[0] == 130  # frame 1's dump would differ
    assert tree(dump) == before_dump and tree(out) == before_out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dump", "frames", "out"]


def test_train_failing_on_a_corrupt_image_leaves_no_run_folder(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    data = Path(shutil.copytree(env.data.parent, tmp_path / "d"))
    for img in (data / "train" / "images").iterdir():
        img.write_bytes(b"\x89PNG\r\n\x1a\n not a png")
    run_dir = tmp_path / "runs" / "r"
    argv = [
        "train",
        "--model",
        "yolov8n-seg",
        "--data",
        str(data / "data.yaml"),
        "--out",
        str(run_dir),
        "--epochs",
        "1",
        "--batch",
        "2",
        "--imgsz",
        "64",
        "--workers",
        "0",
        "--quiet",
    ]
    code, err, _ = run(argv, capfd)
    assert code == 2 and len(err) == 1, err  # no Lightning banner before the one line
    assert not run_dir.exists()


def test_train_interrupted_before_a_checkpoint_leaves_no_run_folder(
    env: Env, tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch
) -> None:
    from slimseg.engine.module import ZooModule

    def interrupt(self, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(ZooModule, "training_step", interrupt)
    run_dir = tmp_path / "r"
    argv = [
        "train",
        "--model",
        "yolov8n-seg",
        "--data",
        str(env.data),
        "--out",
        str(run_dir),
        "--epochs",
        "1",
        "--batch",
        "2",
        "--imgsz",
        "64",
        "--workers",
        "0",
        "--quiet",
    ]
    code, *_ = run(argv, capfd)
    assert code != 0
    assert not run_dir.exists()
