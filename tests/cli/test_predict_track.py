"""``slimseg predict --track``: instance maps, tracks.csv and the animation on a folder of frames
or a video, with a scripted detector (a walker the model misses for two frames, a static chair)
and with a tiny real model; the drawing of coasted masks."""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from conftest import batchnorm_from, open_class_bias
from PIL import Image

import slimseg
from slimseg.cli import predict as predict_cli
from slimseg.cli.main import main
from slimseg.deploy.track_draw import draw_tracked
from slimseg.deploy.track_predict import UNTRACKED_BASE
from slimseg.detections import Prediction
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.objects import Objects

NAMES = ["person", "chair", "car"]
MOBILITY = [1.0, 0.1, 0.8]
HW = (96, 128)
MISSED = (4, 5)  # frames where the scripted model does not see the walker
CHAIR = (90, 20, 120, 60)  # xyxy


def _walker(i: int) -> np.ndarray:
    """``bool [H, W]``: the walker's disc in frame ``i`` (moves 5 px right per frame)."""
    yy, xx = np.mgrid[: HW[0], : HW[1]]
    return (xx - (20 + 5 * i)) ** 2 + (yy - 55) ** 2 <= 12**2


def _frames(n: int = 8) -> list[np.ndarray]:
    """RGB ``uint8 [n][H, W, 3]``: a fixed textured background (ORB features for the camera
    motion), a red walker disc and a brown chair."""
    rng = np.random.default_rng(0)
    back = cv2.GaussianBlur(rng.integers(0, 256, (*HW, 3), dtype=np.uint8), (3, 3), 0)
    out = []
    for i in range(n):
        img = back.copy()
        x1, y1, x2, y2 = CHAIR
        img[y1:y2, x1:x2] = (120, 80, 40)
        img[_walker(i)] = (220, 30, 30)
        out.append(img)
    return out


class ScriptedPredictor:
    """Stands in for ``Predictor``: the walker (score 0.9, missed in ``MISSED``) and the chair
    (score 0.6); ``calls``: the frames it ran on."""

    names, mobility = NAMES, MOBILITY

    def __init__(self) -> None:
        self.calls: list[int] = []

    def predict(self, image, conf=0.25, iou=0.7, max_det=300) -> Prediction:
        red = (image[..., 0] == 220) & (image[..., 1] == 30)  # the frame index from walker x
        i = round((np.flatnonzero(red.any(0)).mean() - 20) / 5)
        self.calls.append(i)
        chair = np.zeros(HW, bool)
        chair[CHAIR[1] : CHAIR[3], CHAIR[0] : CHAIR[2]] = True
        objs = [] if i in MISSED else [(_walker(i), 0, 0.9)]
        objs.append((chair, 1, 0.6))
        objs = [o for o in objs if o[2] > conf]
        boxes = [
            [np.flatnonzero(m.any(0))[0], np.flatnonzero(m.any(1))[0],
             np.flatnonzero(m.any(0))[-1] + 1, np.flatnonzero(m.any(1))[-1] + 1]
            for m, _, _ in objs
        ]  # fmt: skip
        return Prediction(
            boxes=np.array(boxes, np.float32).reshape(-1, 4),
            scores=np.array([o[2] for o in objs], np.float32),
            classes=np.array([o[1] for o in objs], np.int64),
            names=[NAMES[o[1]] for o in objs],
            mobility=[MOBILITY[o[1]] for o in objs],
            masks=np.stack([o[0] for o in objs]) if objs else np.zeros((0, *HW), bool),
            image_hw=HW,
        )


@pytest.fixture
def scripted(monkeypatch) -> ScriptedPredictor:
    fake = ScriptedPredictor()
    monkeypatch.setattr(predict_cli.Predictor, "from_path", lambda *a, **k: fake)
    return fake


def _folder(root: Path, n: int = 8) -> Path:
    src = root / "frames"
    src.mkdir()
    for i, img in enumerate(_frames(n)):
        cv2.imwrite(str(src / f"{i:04d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    return src


def _read_tracks(out: Path, stems: list[str]) -> list[dict]:
    """tracks.csv, checked against the instance maps: every frame's non-zero map values are
    exactly the ``map_id`` of that frame's rows whose mask shows."""
    with (out / "tracks.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert sorted(p.stem for p in (out / "tracks").glob("*.png")) == sorted(stems)
    for i, stem in enumerate(stems):
        imap = cv2.imread(str(out / "tracks" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        assert imap.dtype == np.uint16 and imap.shape == HW
        mine = [r for r in rows if int(r["frame"]) == i]
        assert all(r["stem"] == stem for r in mine)
        ids = {int(r["map_id"]) for r in mine}
        assert set(np.unique(imap).tolist()) - {0} <= ids
        for r in mine:
            tid, mid = int(r["track_id"]), int(r["map_id"])
            assert mid == tid if tid >= 0 else mid >= UNTRACKED_BASE
    assert not list(out.rglob(".*tmp*"))  # no temporary files left behind
    return rows


def test_folder_coasts_the_missed_walker(scripted, tmp_path, capsys):
    src, out = _folder(tmp_path), tmp_path / "out"
    argv = ["predict", "--model", "m.onnx", "--source", str(src), "--out", str(out), "--track"]
    assert main([*argv, "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "8 frame(s) (model on 8), 1 track(s), 2 predicted mask(s)" in printed
    assert "ms/frame" in printed and str(out / "tracks.gif") in printed
    assert scripted.calls == list(range(8))
    rows = _read_tracks(out, [f"{i:04d}" for i in range(8)])
    walker = [r for r in rows if r["class"] == "person"]
    assert [int(r["frame"]) for r in walker] == list(range(8))
    assert {r["track_id"] for r in walker} == {"1"}  # the same id after the gap
    assert [(r["source"], r["misses"], r["score"]) for r in walker if r["source"] != "det"] == [
        ("coast", "1", ""),
        ("coast", "2", ""),
    ]
    chair = [r for r in rows if r["class"] == "chair"]
    assert len(chair) == 8 and {(r["track_id"], r["map_id"]) for r in chair} == {
        ("-1", str(UNTRACKED_BASE))
    }
    # the coasted mask is in the map, ahead of where the walker was last seen
    imap = cv2.imread(str(out / "tracks" / "0004.png"), cv2.IMREAD_UNCHANGED)
    xs = np.flatnonzero((imap == 1).any(0))
    assert len(xs) and xs.mean() > 20 + 5 * 3
    gif = Image.open(out / "tracks.gif")
    assert gif.n_frames == 8 and gif.size == (HW[1], HW[0])
    if (out / "tracks.mp4").exists():  # mp4v where OpenCV writes it
        cap = cv2.VideoCapture(str(out / "tracks.mp4"))
        assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 8
        cap.release()


def test_segment_every_runs_the_model_on_half_the_frames(scripted, tmp_path, capsys):
    src, out = _folder(tmp_path), tmp_path / "out"
    argv = ["predict", "--model", "m.onnx", "--source", str(src), "--out", str(out)]
    assert main([*argv, "--track", "--rate", "2", "--quiet"]) == 0
    assert "8 frame(s) (model on 4)" in capsys.readouterr().out
    assert scripted.calls == [0, 2, 4, 6]
    rows = _read_tracks(out, [f"{i:04d}" for i in range(8)])
    carried = {int(r["frame"]) for r in rows if r["source"] == "carried"}
    assert carried and carried <= {1, 3, 5, 7}
    # without --track, --rate is refused in one line
    assert main([*argv, "--rate", "2"]) == 2
    assert "needs the track stage" in capsys.readouterr().err


def test_single_image_is_refused(scripted, tmp_path, capsys):
    image = _folder(tmp_path) / "0000.png"
    code = main(["predict", "--model", "m.onnx", "--source", str(image), "--track"])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1 and "--track" in err and "one image" in err
    assert scripted.calls == []


def _tracked(source: str) -> Objects:
    mask = np.zeros(HW, bool)
    mask[30:70, 40:80] = True
    return Objects(
        boxes=np.array([[30, 20, 90, 80]], np.float32),  # around the mask, on plain grey
        classes=np.zeros(1, np.int64),
        masks=mask[None],
        hw=HW,
        mobility=np.ones(1, np.float32),
        track_ids=np.array([3]),
        source=[source],
        misses=np.array([0 if source == "det" else 2]),
        scores=np.array([0.8 if source == "det" else 0.0], np.float32),
        det_index=np.array([0 if source == "det" else -1]),
    )


def test_coasted_masks_are_drawn_differently():
    image = np.full((*HW, 3), 128, np.uint8)
    det = draw_tracked(image, _tracked("det"), NAMES)
    coast = draw_tracked(image, _tracked("coast"), NAMES, lost=np.array([2]))
    inner = (slice(35, 50), slice(50, 70))  # inside the mask, away from outline and labels
    assert len(np.unique(det[inner].reshape(-1, 3), axis=0)) == 1  # a flat translucent fill
    assert len(np.unique(coast[inner].reshape(-1, 3), axis=0)) >= 2  # hatched
    assert (det[inner] != coast[inner]).any(-1).mean() > 0.3
    # the box: solid for the detection, dashed (gaps) for the coasted mask
    edge_det, edge_coast = det[25:60, 30], coast[25:60, 30]  # its left edge
    assert (edge_det != 128).any(-1).all()
    assert (edge_coast == 128).all(-1).any() and (edge_coast != 128).any(-1).any()
    assert not np.array_equal(image, det) and image.max() == image.min() == 128  # a copy


# -- a tiny real model ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory) -> Path:
    """yolov8n-seg at 64 px, BatchNorm statistics from one batch and class bias 0 (so that
    random weights give scores above the threshold), fused, as ``.pt`` weights."""
    torch.manual_seed(0)
    model = slimseg.build_model("yolov8n-seg", num_classes=len(NAMES))
    batch = torch.from_numpy(np.stack(_frames(4))).permute(0, 3, 1, 2).float() / 255
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batchnorm_from(model, torch.nn.functional.interpolate(batch, size=(64, 64)))
    fused = open_class_bias(model).fuse()
    info = WeightsInfo(fused.spec, NAMES, MOBILITY, train_config={"imgsz": 64})
    return save_weights(tmp_path_factory.mktemp("tiny") / "model.pt", fused, info)


def test_real_model_on_a_folder_and_a_video(tiny_weights, tmp_path, capsys):
    src = _folder(tmp_path)
    base = ["predict", "--model", str(tiny_weights), "--max-det", "4", "--threads", "1"]
    out = tmp_path / "folder"
    assert main([*base, "--source", str(src), "--out", str(out), "--track", "--quiet"]) == 0
    assert "8 frame(s) (model on 8)" in capsys.readouterr().out
    _read_tracks(out, [f"{i:04d}" for i in range(8)])
    assert Image.open(out / "tracks.gif").n_frames == 8

    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (HW[1], HW[0]))
    if not writer.isOpened():
        pytest.skip("OpenCV has no MJPG writer here")
    for img in _frames(6):
        writer.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    writer.release()
    out = tmp_path / "video"
    argv = [*base, "--source", str(video), "--out", str(out), "--track", "no-coast"]
    assert main([*argv, "--rate", "3", "--quiet"]) == 0
    assert "6 frame(s) (model on 2)" in capsys.readouterr().out
    _read_tracks(out, [f"frame_{i:06d}" for i in range(6)])
    assert Image.open(out / "tracks.gif").n_frames == 6
