"""A command writes only what it owns, reads only inside the roots it was given, and leaves
no half-written output (issue 42, classes 1, 2 and 4; :mod:`slimseg.utils.outputs`).

Each case runs the CLI in-process on tiny shared fixtures and asserts the outcome: a refusal
is exit 2 with one stderr line naming the flag or file, and the user's files byte for byte as
they were.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from outputs_env import (
    IMGSZ,
    USER,
    Env,
    _dyn,
    _predict,
    _slam,
    _sweep,
    frames_folder,
    make_env,
    refused,
    run,
    tree,
    user_folder,
)

from slimseg.errors import SlimsegError
from slimseg.utils.atomic import staged_dir
from slimseg.utils.outputs import MANIFEST, unique_stems


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Env:
    return make_env(tmp_path_factory.mktemp("outputs"))


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
    # the weights as --out: an export is an .onnx file, so this --out is refused before any
    # other check (an --out ending in .onnx can never be the .pt it reads)
    refused([*argv, "--out", str(best)], capfd, "--out", ".onnx")
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
