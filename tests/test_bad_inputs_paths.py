"""Paths read from data files stay inside their roots, and no output is ever left half
written (issue 42, classes 2 and 4; :mod:`slimseg.utils.outputs`). Fixtures and helpers:
``outputs_env``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from outputs_env import (
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
)


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Env:
    return make_env(tmp_path_factory.mktemp("outputs"))


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
    argv = _train(data / "data.yaml", run_dir)
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
    argv = _train(env.data, run_dir)
    code, *_ = run(argv, capfd)
    assert code != 0
    assert not run_dir.exists()


def _train(data: Path, out: Path) -> list[str]:
    """One tiny epoch of ``slimseg train`` on ``data`` into ``out``."""
    return ["train", "--model", "yolov8n-seg", "--data", str(data), "--out", str(out),
            "--epochs", "1", "--batch", "2", "--imgsz", "64", "--workers", "0",
            "--quiet"]  # fmt: skip
