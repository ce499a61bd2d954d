"""``--rerun FILE.rrd`` on ``slimseg dynamic``, ``predict --track`` and ``slam-eval``, read back
with rerun-sdk's own reader (``rerun.chunk.RrdReader``): one colour image, depth, class-coloured
mask (whose masked pixels are the run's ``masks/`` PNG's), box set and keypoint sets per frame;
one trajectory per condition beside the ground truth; refusals before any work."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import class_map_weights

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence, mask_name

pytest.importorskip("rerun")

FRAMES = 12


class Env:
    def __init__(self, root: Path) -> None:
        generate(root / "d", 0, 0, 64, 0, sequences=1, frames=FRAMES, seq_size=(160, 128),
                 progress=False)  # fmt: skip
        self.seq = root / "d" / "sequences" / "seq_000"
        self.weights = class_map_weights(self.seq, root / "w.pt")

    def common(self, chain: bool = True) -> list[str]:
        """The model at score threshold 0: the chain's (``--set conf=0``) or predict's."""
        conf = ["--set", "conf=0"] if chain else ["--conf", "0"]
        return ["--model", str(self.weights), *conf, "--threads", "1", "--quiet"]


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Env:
    return Env(tmp_path_factory.mktemp("rerun"))


def read_rrd(path: Path) -> dict[str, list[dict]]:
    """Every entity's rows (``{column: value}``) as rerun-sdk reads the file back."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict]] = {}
    (store,) = RrdReader(path).recordings()
    for chunk in RrdReader(path).store(store=store).stream():
        rows.setdefault(chunk.entity_path, []).extend(chunk.to_record_batch().to_pylist())
    return rows


def _frames(rows: list[dict]) -> list[int]:
    return sorted(r["frame"] for r in rows)


def test_dynamic_writes_one_mask_per_frame(env: Env, tmp_path: Path, capsys) -> None:
    rrd = tmp_path / "dyn.rrd"
    out = tmp_path / "out"
    cmd = ["dynamic", "--sequence", str(env.seq), "--out", str(out), "--track", "--rerun",
           str(rrd), *env.common()]  # fmt: skip
    assert main(cmd) == 0
    assert f"Rerun recording of {FRAMES} frames: {rrd}" in capsys.readouterr().out
    rows = read_rrd(rrd)
    per_frame = [
        *("/camera/image", "/camera/depth", "/camera/image/dynamic_mask"),
        *("/camera/image/objects", "/camera/image/keypoints/static"),
        *("/camera/image/keypoints/dynamic", "/timing/model_ms", "/timing/latency_ms"),
    ]
    for entity in per_frame:
        assert _frames(rows[entity]) == list(range(FRAMES)), entity
    (ctx,) = rows["/"]
    classes = {
        c["class_id"]: c["class_description"]["info"] for c in ctx["AnnotationContext:context"][0]
    }
    assert {k: v["label"] for k, v in classes.items()} == {
        0: "static",
        1: "person",
        2: "chair",
        3: "dynamic (dilation)",
        4: "ground truth (dynamic)",
    }
    assert classes[0]["color"] & 0xFF == 0 and len({v["color"] for v in classes.values()}) == 5
    tum = TumSequence(env.seq)
    masked = 0
    for row in rows["/camera/image/dynamic_mask"]:
        fmt = row["SegmentationImage:format"][0]
        buf = bytes(row["SegmentationImage:buffer"][0])
        assert len(buf) == fmt["height"] * fmt["width"]  # ids 0-3 fit in uint8
        seg = np.frombuffer(buf, np.uint8).reshape(fmt["height"], fmt["width"])
        png = cv2.imread(str(out / "masks" / mask_name(tum.frames[row["frame"]][0][0])), 0)
        assert np.array_equal(seg > 0, png > 0)
        assert set(np.unique(seg)) <= {0, 1, 2, 3}  # static, person, chair, dilation only
        masked += int((seg == 1).sum())
    assert masked > 0  # person pixels, coloured as the class
    for row in rows["/camera/image/ground_truth"]:  # the synthetic sequence's dynamic/ masks
        fmt = row["SegmentationImage:format"][0]
        ids = np.frombuffer(bytes(row["SegmentationImage:buffer"][0]), np.uint8)
        truth = cv2.imread(str(env.seq / "dynamic" / mask_name(tum.frames[row["frame"]][0][0])), 0)
        assert np.array_equal(ids.reshape(fmt["height"], fmt["width"]), np.where(truth > 0, 4, 0))
    assert _frames(rows["/camera/image/ground_truth"]) == list(range(FRAMES))
    labels = [x for r in rows["/camera/image/objects"] for x in r["Boxes2D:labels"] or []]
    assert labels and any(x.startswith("#") and " p " in x for x in labels)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dyn.rrd", "out"]  # nothing staged


def test_predict_track_writes_one_mask_per_frame(env: Env, tmp_path: Path) -> None:
    rrd = tmp_path / "pred.rrd"
    rrd.write_bytes(b"RRF2" + bytes(12))  # an earlier recording (by its magic) is replaced
    cmd = ["predict", "--source", str(env.seq / "rgb"), "--out", str(tmp_path / "p"),
           "--track", "--rerun", str(rrd), *env.common(chain=False)]  # fmt: skip
    assert main(cmd) == 0
    rows = read_rrd(rrd)
    assert _frames(rows["/camera/image/dynamic_mask"]) == list(range(FRAMES))
    assert _frames(rows["/camera/image"]) == list(range(FRAMES))
    assert "/camera/depth" not in rows  # predict reads colour only
    assert "/camera/image/ground_truth" not in rows


def test_slam_eval_writes_one_trajectory_per_condition(env: Env, tmp_path: Path, capsys):
    pytest.importorskip("evo")
    rrd = tmp_path / "slam.rrd"
    cmd = ["slam-eval", "--sequence", str(env.seq), "--engine", "dense", "--modes",
           "raw,gt,fusion", "--out", str(tmp_path / "s"), "--json", "--rerun", str(rrd),
           *env.common()]  # fmt: skip
    assert main(cmd) == 0
    table = {r["condition"]: r["ate_rmse"] for r in json.loads(capsys.readouterr().out)}
    rows = read_rrd(rrd)
    conditions = [c for c in table if c in ("raw", "gt", "fusion")]
    assert len(conditions) == 3
    for c in conditions:
        (strip,) = rows[f"/world/{c}"]
        (points,) = strip["LineStrips3D:strips"]
        assert len(points) >= FRAMES - 2 and len(points[0]) == 3
        (ate,) = rows[f"/ate/{c}"]
        assert ate["Scalars:scalars"] == [pytest.approx(table[c], abs=5e-5)]
    (gt,) = rows["/world/ground_truth"]
    assert len(gt["LineStrips3D:strips"][0]) >= FRAMES
    assert "/results" in rows


def test_rerun_refusals_before_any_work(env: Env, tmp_path: Path, capsys) -> None:
    base = ["dynamic", "--sequence", str(env.seq), *env.common()]
    user = tmp_path / "notes.rrd"
    user.write_text("my notes")
    cases = [
        (["--out", str(tmp_path / "o"), "--rerun", str(tmp_path / "x.txt")], "a .rrd file"),
        (["--out", str(tmp_path / "o"), "--rerun", str(tmp_path / "o" / "x.rrd")], "lies in --out"),
        (["--out", str(tmp_path / "o"), "--rerun", str(user)], "not one slimseg wrote"),
    ]
    for extra, message in cases:
        assert main([*base, *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.rrd"]
    assert user.read_text() == "my notes"
    pred = ["predict", "--source", str(env.seq / "rgb"), "--out", str(tmp_path / "p"),
            "--rerun", str(tmp_path / "p.rrd"), *env.common(chain=False)]  # fmt: skip
    assert main(pred) == 2 and "add --track" in capsys.readouterr().err


def test_without_rerun_sdk_the_option_names_the_extra(env: Env, tmp_path: Path, capsys,
                                                       monkeypatch) -> None:  # fmt: skip
    import sys

    monkeypatch.setitem(sys.modules, "rerun", None)
    cmd = ["dynamic", "--sequence", str(env.seq), "--out", str(tmp_path / "o"), "--rerun",
           str(tmp_path / "x.rrd"), *env.common()]  # fmt: skip
    assert main(cmd) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install 'slimseg[viz]'" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("fails", ["save", "flush"])
def test_a_recording_that_cannot_be_finished_fails_the_run_whole(
    env: Env, tmp_path: Path, capsys, monkeypatch, fails: str
) -> None:
    """A read-only folder (``save`` fails) or a full disk (``flush`` fails, rerun's file
    writer gone): one line, exit 2, ``--out`` never published, no staged ``.rrd`` left."""
    import rerun as rr

    def broken(self, *args, **kwargs) -> None:
        raise RuntimeError("\x1b[31mFile-writer thread shut down prematurely\x1b[0m")

    monkeypatch.setattr(rr.RecordingStream, fails, broken)
    cmd = ["dynamic", "--sequence", str(env.seq), "--out", str(tmp_path / "out"), "--rerun",
           str(tmp_path / "r.rrd"), *env.common()]  # fmt: skip
    assert main(cmd) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--rerun" in err and "\x1b" not in err, err
    assert ("could not be finished" if fails == "flush" else "cannot write") in err
    assert list(tmp_path.iterdir()) == []
