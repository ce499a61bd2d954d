"""Splits read from annotated sequences, and the sequence-world training frames of synth."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from slimseg.cli.main import main
from slimseg.data.check import check_dataset
from slimseg.data.coco import CocoDataset
from slimseg.data.config import load_data_config
from slimseg.data.synth import generate
from slimseg.data.synth.world_frames import FIRST_INDEX, WORLD_PRESETS, WorldSplits
from slimseg.detections import FrameDetections
from slimseg.errors import SlimsegError
from slimseg.eval.coco_eval import CocoEvaluator

pytestmark = pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")
WORLDS = WorldSplits(train=2, val=1, frames=9, step=3)  # 3 frames per world


@pytest.fixture(scope="module")
def worlds(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("worlds") / "ds"
    generate(out, 0, 0, 64, seed=5, seq_size=(160, 120), progress=False, worlds=WORLDS)
    return out


def _write_yaml(path: Path, root: Path, **fields: object) -> Path:
    base = {"path": str(root), "names": ["person", "dog", "sports ball", "bottle", "chair", "tv"]}
    path.write_text(yaml.safe_dump(base | fields))
    return path


def test_synth_writes_world_splits_and_data_yaml(worlds: Path) -> None:
    cfg = yaml.safe_load((worlds / "data.yaml").read_text())
    assert cfg["train"] == {"sequences": ["train_sequences/000_walking_xyz",
                                          "train_sequences/001_walking_halfsphere"]}  # fmt: skip
    assert cfg["val"] == {"sequences": ["val_sequences/000_walking_xyz"]}
    assert WORLD_PRESETS[:2] == ("walking_xyz", "walking_halfsphere")
    seq = worlds / "train_sequences" / "001_walking_halfsphere"
    assert len(list((seq / "rgb").glob("*.png"))) == 3  # every 3rd of 9 frames
    assert not (seq / "dynamic").exists() and not (seq / "background").exists()
    stamps = [float(line.split()[0]) for line in (seq / "rgb.txt").read_text().splitlines()[3:]]
    assert np.allclose(np.diff(stamps), 0.1, atol=1e-5)  # true timestamps, 10 Hz
    assert (
        "--seq-train 2 --seq-val 1 --seq-frames 9 --seq-step 3"
        in (worlds / "data.yaml").read_text()
    )


def test_world_seeds_never_meet_an_evaluation_sequence(tmp_path: Path) -> None:
    """World k of train is sequence index FIRST_INDEX + k: rendering that sequence directly
    gives the same frame, and an evaluation sequence (index 0) another one."""
    from slimseg.data.synth import build_world, render_sequence_frame

    a = build_world(5, FIRST_INDEX["train"], 9, 160, 120, preset="walking_xyz")
    b = build_world(5, 0, 9, 160, 120, preset="walking_xyz")
    fa, fb = render_sequence_frame(a, 0).frame.rgb, render_sequence_frame(b, 0).frame.rgb
    assert not np.array_equal(fa, fb)


def test_merged_split_reads_every_stride_th_frame_with_unique_ids(
    worlds: Path, tmp_path: Path
) -> None:
    cfg = load_data_config(worlds / "data.yaml")
    train = CocoDataset.from_config(cfg, "train")
    assert len(train) == 6 and train.images_dir == (worlds / "train_sequences").resolve()
    ids = [r.id for r in train.records]
    assert ids == list(range(1, 7))
    assert train.records[3].file_name.startswith("001_walking_halfsphere/rgb/")
    sample = train[4]
    assert sample.image.shape == (120, 160, 3) and len(sample.classes) > 0
    # stride 2 on top: frames 0 and 2 of each world's three
    raw = yaml.safe_load((worlds / "data.yaml").read_text())
    y = _write_yaml(tmp_path / "stride.yaml", worlds, train=dict(raw["train"], stride=2))
    assert len(CocoDataset.from_config(load_data_config(y), "train")) == 4


def test_merged_ground_truth_scores_itself_one(worlds: Path) -> None:
    """The merged dict is the evaluator's ground truth: its own instances score mAP 1."""
    val = CocoDataset.from_config(load_data_config(worlds / "data.yaml"), "val")
    ev = CocoEvaluator.from_dataset(val)
    dets = []
    for i in range(len(val)):
        s = val[i]
        dets.append(FrameDetections(s.boxes, np.ones(len(s.classes), np.float32), s.classes,
                                    s.image.shape[:2], masks=s.masks.astype(bool)))  # fmt: skip
    ev.update([val[i].image_id for i in range(len(val))], dets)
    res = ev.summarize()
    assert res["box"]["map50_95"] == pytest.approx(1.0) and res["mask"]["map50_95"] == 1.0


def test_check_and_show_read_sequence_splits(worlds: Path, tmp_path: Path, capsys) -> None:
    report = check_dataset(worlds / "data.yaml", progress=False)
    assert [s.num_images for s in report.splits] == [6, 3] and report.count("error") == 0
    assert main(["data", "show", "--data", str(worlds / "data.yaml"), "--out",
                 str(tmp_path / "show.png"), "--count", "4"]) == 0  # fmt: skip
    assert (tmp_path / "show.png").is_file()


@pytest.mark.parametrize(
    "case",
    ["no_annotations", "missing_frame", "categories_differ", "bad_stride", "depth_with_seq"],
)
def test_bad_sequence_splits_get_one_line(worlds: Path, tmp_path: Path, case: str) -> None:
    root = tmp_path / "ds"
    shutil.copytree(worlds, root)
    seqs = ["train_sequences/000_walking_xyz", "train_sequences/001_walking_halfsphere"]
    split: dict = {"sequences": seqs}
    second = root / seqs[1]
    if case == "no_annotations":
        (second / "annotations.json").unlink()
        expect = "has no annotations.json"
    elif case == "missing_frame":
        next(iter(sorted((second / "rgb").glob("*.png")))).unlink()
        expect = "is listed but"
    elif case == "categories_differ":
        data = json.loads((second / "annotations.json").read_text())
        data["categories"][1]["name"] = "cat"
        (second / "annotations.json").write_text(json.dumps(data))
        expect = "differ from"
    elif case == "bad_stride":
        split["stride"] = 0
        expect = "'train.stride'"
    else:
        split["depth"] = "train_sequences"
        expect = "'train.depth'"
    y = _write_yaml(root / "bad.yaml", root, train=split)
    with pytest.raises(SlimsegError, match=expect) as err:
        CocoDataset.from_config(load_data_config(y), "train")
    assert "\n" not in str(err.value)
    assert main(["data", "check", str(y)]) == 2


def test_regenerate_comment_writes_the_same_world_frames(worlds: Path, tmp_path: Path) -> None:
    import shlex

    comment = (worlds / "data.yaml").read_text().splitlines()[1]
    argv = shlex.split(comment.removeprefix("# ").replace("<dir>", str(tmp_path / "regen")))
    assert main([*argv[1:], "--quiet"]) == 0

    def files(root: Path) -> dict[str, bytes]:
        return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*")
                if p.is_file()}  # fmt: skip

    assert files(tmp_path / "regen") == files(worlds)
