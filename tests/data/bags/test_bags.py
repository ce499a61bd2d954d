"""ROS bags as sequences and as outputs: every bag kind rosbags writes (ROS 1, rosbag2 SQLite and
MCAP, bare MCAP; raw, compressed; 16UC1, 32FC1, compressedDepth; rgb8, bgr8) reads back as the
same frames as the TUM folder it was made from, ``slimseg dynamic`` gives byte-identical masks
on a bag and on the folder, masks written to MCAP read back with the independent ``mcap``
package, and bad bags end in one line, exit 2, nothing written."""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import class_map_weights
from test_bad_inputs_content import png_bomb

from slimseg.cli.main import main
from slimseg.data.bags.from_tum import DEPTH_TOPIC, FRAME_ID, POSE_TOPIC, RGB_TOPIC, tum_to_bag
from slimseg.data.bags.header import Header, stamp_ns
from slimseg.data.bags.sequence import BagSequence
from slimseg.data.bags.writer import BagWriter
from slimseg.data.sequence_source import open_sequence
from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence, mask_name, read_trajectory
from slimseg.errors import SlimsegError
from slimseg.sequence.mask_bag import FOLDER_FRAME_ID, MASK_TOPIC
from slimseg.utils.atomic import write_png

pytest.importorskip("rosbags")

# name → (storage, colour, depth); the folder's depth is kept on whole millimetres, so 16UC1
# and compressedDepth hold it exactly
BAGS = {
    "raw.bag": (None, "rgb8", "32FC1"),
    "bgr_mm.bag": (None, "bgr8", "16UC1"),
    "png_cdepth.bag": (None, "png", "compressedDepth"),
    "sqlite_raw": ("sqlite3", "rgb8", "16UC1"),
    "sqlite_png": ("sqlite3", "png", "32FC1"),
    "mcap_dir_bgr": ("mcap", "bgr8", "32FC1"),
    "bare.mcap": (None, "rgb8", "compressedDepth"),
    "jpeg.mcap": (None, "jpeg", "16UC1"),
}


class Env:
    def __init__(self, root: Path) -> None:
        generate(root / "d", 0, 0, 64, 0, sequences=1, frames=5, seq_size=(160, 128),
                 progress=False)  # fmt: skip
        self.seq = root / "d" / "sequences" / "seq_000"
        for p in (self.seq / "depth").iterdir():  # whole millimetres (5 units at 5000/m)
            raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            write_png(p, (np.round(raw / 5.0) * 5).astype(np.uint16))
        self.bags = {}
        for name, (storage, colour, depth) in BAGS.items():
            self.bags[name] = root / "bags" / name
            tum_to_bag(self.seq, self.bags[name], storage, colour, depth)
        self.weights = class_map_weights(self.seq, root / "w.pt")
        self.folder_out = root / "folder_out"
        assert main(self.dynamic(self.seq, self.folder_out)) == 0

    def dynamic(self, seq: Path, out: Path, *extra: str) -> list[str]:
        return ["dynamic", "--model", str(self.weights), "--sequence", str(seq), "--out",
                str(out), "--set", "conf=0", "--threads", "1", "--quiet", *extra]  # fmt: skip


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Env:
    return Env(tmp_path_factory.mktemp("bags"))


@pytest.mark.parametrize("name", list(BAGS))
def test_every_bag_kind_reads_as_the_folders_frames(env: Env, name: str) -> None:
    with TumSequence(env.seq) as tum, open_sequence(env.bags[name]) as bag:
        assert isinstance(bag, BagSequence) and len(bag) == len(tum)
        assert bag.camera == tum.camera and "camera_info" in bag.camera_source
        assert [f[0][1] for f in bag.frames] == [f"rgb/{mask_name(t)}" for (t, _), _ in tum.frames]
        for i in [*range(len(tum)), 1, 0]:  # in order, then back (the cursor restarts)
            rgb, depth, t = bag.load(i)
            ref_rgb, ref_depth, ref_t = tum.load(i)
            assert t == ref_t and depth.dtype == np.float32
            assert np.array_equal(depth, ref_depth)
            if BAGS[name][1] == "jpeg":
                assert np.abs(rgb.astype(int) - ref_rgb).mean() < 8
            else:
                assert np.array_equal(rgb, ref_rgb)
        assert bag.headers[0] == Header(stamp_ns(tum.frames[0][0][0]), FRAME_ID)
    assert bag.closed  # leaving the block closed the recording
    with pytest.raises(SlimsegError, match="was closed; open it again"):
        bag.load(0)


@pytest.mark.parametrize("name", ["raw.bag", "sqlite_png", "bare.mcap"])
def test_dynamic_on_a_bag_gives_the_folders_masks(env: Env, tmp_path: Path, name: str) -> None:
    out = tmp_path / "out"
    assert main(env.dynamic(env.bags[name], out)) == 0
    want = sorted((env.folder_out / "masks").iterdir())
    got = sorted((out / "masks").iterdir())
    assert [p.name for p in got] == [p.name for p in want]
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(got, want, strict=True))
    assert any(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).any() for p in want)  # not all empty


def _cdr_image(data: bytes) -> tuple[int, int, str, int, int, str, bytes]:
    """An independent parse of a CDR ``sensor_msgs/Image``: ``(sec, nanosec, frame_id, height,
    width, encoding, pixels)``."""
    pos = 4  # encapsulation header; alignment counts from here

    def take(fmt: str, size: int):
        nonlocal pos
        pos += -(pos - 4) % size
        val = struct.unpack_from("<" + fmt, data, pos)[0]
        pos += struct.calcsize(fmt)
        return val

    def text() -> str:
        nonlocal pos
        n = take("I", 4)
        s = data[pos : pos + n - 1].decode()
        pos += n
        return s

    sec, nsec = take("i", 4), take("I", 4)
    frame = text()
    h, w = take("I", 4), take("I", 4)
    enc = text()
    take("B", 1)
    take("I", 4)
    n = take("I", 4)
    return sec, nsec, frame, h, w, enc, data[pos : pos + n]


def test_masks_written_to_mcap_read_back_with_the_mcap_package(env: Env, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    out = tmp_path / "masks.mcap"
    assert main(env.dynamic(env.bags["sqlite_raw"], out, "--bag-masked-rgb")) == 0
    tum = TumSequence(env.seq)
    with out.open("rb") as f:
        msgs = [(c.topic, s.name, m) for s, c, m in make_reader(f).iter_messages()]
    masks = [(m, _cdr_image(m.data)) for topic, schema, m in msgs if topic == MASK_TOPIC]
    assert {s for _, s, _ in msgs} == {"sensor_msgs/msg/Image"}
    assert len(masks) == len(tum) and sum(t != MASK_TOPIC for t, _, _ in msgs) == len(tum)
    for i, (m, (sec, nsec, frame, h, w, enc, pixels)) in enumerate(masks):
        t = tum.frames[i][0][0]
        assert sec * 1_000_000_000 + nsec == stamp_ns(t) == m.log_time and frame == FRAME_ID
        png = cv2.imread(str(env.folder_out / "masks" / mask_name(t)), cv2.IMREAD_GRAYSCALE)
        assert (h, w, enc) == (128, 160, "mono8")
        assert np.array_equal(np.frombuffer(pixels, np.uint8).reshape(h, w), png)
    assert [p.name for p in tmp_path.iterdir()] == ["masks.mcap"]  # no staging left


def test_masks_of_a_folder_written_to_mcap_carry_its_stamps(env: Env, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    out = tmp_path / "m.mcap"
    assert main(env.dynamic(env.seq, out)) == 0
    with out.open("rb") as f:
        heads = [_cdr_image(m.data)[:3] for _, _, m in make_reader(f).iter_messages()]
    want = [
        (*divmod(stamp_ns(t), 10**9), FOLDER_FRAME_ID) for (t, _), _ in TumSequence(env.seq).frames
    ]
    assert heads == want


@pytest.mark.parametrize("suffix", ["masks.bag", "rosbag2_sqlite"])
def test_masks_written_as_ros1_bag_and_rosbag2_folder(env: Env, tmp_path: Path, suffix: str):
    from rosbags.highlevel import AnyReader

    out = tmp_path / suffix
    extra = () if suffix.endswith(".bag") else ("--bag-storage", "sqlite3")
    assert main(env.dynamic(env.bags["raw.bag"], out, *extra)) == 0
    tum = TumSequence(env.seq)
    with AnyReader([out]) as reader:
        conns = [c for c in reader.connections if c.topic == MASK_TOPIC]
        got = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in got] == [
        stamp_ns(t) for (t, _), _ in tum.frames
    ]
    png = cv2.imread(str(env.folder_out / "masks" / mask_name(tum.frames[2][0][0])), 0)
    assert got[2].encoding == "mono8" and np.array_equal(got[2].data.reshape(128, 160), png)


def test_predict_on_a_bags_colour_topic_as_on_the_folder(env: Env, tmp_path: Path) -> None:
    base = ["predict", "--model", str(env.weights), "--threads", "1", "--quiet"]
    assert main([*base, "--source", str(env.seq / "rgb"), "--out", str(tmp_path / "f")]) == 0
    bag = ["--source", str(env.bags["mcap_dir_bgr"])]
    assert main([*base, *bag, "--out", str(tmp_path / "b")]) == 0
    want = sorted((tmp_path / "f").glob("*_classes.png"))
    got = sorted((tmp_path / "b").glob("*_classes.png"))
    assert len(want) == 5 and [p.name for p in got] == [p.name for p in want]
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(got, want, strict=True))
    assert main([*base, *bag, "--track", "--out", str(tmp_path / "t")]) == 0
    assert sorted(p.name for p in (tmp_path / "t" / "tracks").iterdir()) == [
        p.name.replace("_classes", "") for p in want
    ]


def test_slam_vocab_from_a_bags_colour_frames(env: Env, tmp_path: Path) -> None:
    from slimseg.slam.vocab import build_vocabulary

    out = tmp_path / "voc.txt"
    argv = ["slam", "vocab", "--images", str(env.bags["bgr_mm.bag"]), "--out", str(out)]
    assert main([*argv, "--k", "4", "--levels", "2", "--max-images", "3"]) == 0
    tum = TumSequence(env.seq)  # frames 0, 1, 3 of 5: the thinning of --images files
    grey = [cv2.cvtColor(tum.load(i)[0], cv2.COLOR_RGB2GRAY) for i in (0, 1, 3)]
    build_vocabulary(grey, tmp_path / "ref.txt", 4, 2)
    assert out.read_bytes() == (tmp_path / "ref.txt").read_bytes()


def test_bag2tum_gives_the_folder_back(env: Env, tmp_path: Path, capsys) -> None:
    out = tmp_path / "tum"
    assert main(["data", "bag2tum", "--bag", str(env.bags["png_cdepth.bag"]), "--out", str(out),
                 "--quiet"]) == 0  # fmt: skip
    assert "5 frame pairs written" in capsys.readouterr().out
    back, ref = TumSequence(out), TumSequence(env.seq)
    assert back.camera == ref.camera and back.camera_source == "camera.yaml"
    for i in range(len(ref)):
        for a, b in zip(back.load(i), ref.load(i), strict=True):
            assert np.array_equal(a, b)


def test_bag2tum_writes_the_pose_topic_as_groundtruth(env: Env, tmp_path: Path) -> None:
    out = tmp_path / "tum"
    argv = ["data", "bag2tum", "--bag", str(env.bags["sqlite_raw"]), "--out", str(out)]
    assert main([*argv, "--pose-topic", POSE_TOPIC, "--quiet"]) == 0
    got, want = (
        read_trajectory(out / "groundtruth.txt"),
        read_trajectory(env.seq / "groundtruth.txt"),
    )
    assert got.shape == want.shape and np.allclose(got, want, rtol=0, atol=1e-9)


def test_slam_eval_on_a_bag_scores_as_on_the_folder(env: Env, tmp_path: Path, capsys) -> None:
    pytest.importorskip("evo")
    base = ["slam-eval", "--engine", "dense", "--modes", "raw,fusion", "--json", "--quiet"]
    base += ["--model", str(env.weights), "--set", "conf=0", "--threads", "1"]
    ates = []
    for k, source in enumerate((
        [str(env.seq)],
        [str(env.bags["bare.mcap"]), "--pose-topic", POSE_TOPIC],
        [str(env.bags["raw.bag"]), "--groundtruth", str(env.seq / "groundtruth.txt")],
    )):  # fmt: skip
        capsys.readouterr()
        assert main([*base, "--out", str(tmp_path / str(k)), "--sequence", *source]) == 0
        rows = json.loads(capsys.readouterr().out)
        ates.append([r["ate_rmse"] for r in rows])
    assert None not in ates[0] and ates == [ates[0]] * 3  # the dense engine is deterministic
    bare = [*base, "--out", str(tmp_path / "x"), "--sequence", str(env.bags["raw.bag"])]
    assert main(bare) == 2
    assert "give --groundtruth FILE (TUM) or --pose-topic" in capsys.readouterr().err


def _bag(path: Path, ros1: bool = True) -> BagWriter:
    return BagWriter(path.with_suffix(".bag" if ros1 else ".mcap"))


def _frame(w: BagWriter, topic: str, t: float, enc: str = "rgb8", log: float | None = None) -> None:
    dtype = {"16UC1": np.uint16, "32FC1": np.float32}.get(enc, np.uint8)
    shape = (48, 64) if enc in ("16UC1", "32FC1", "mono8") else (48, 64, 3)
    fill = {"16UC1": 1500, "32FC1": 1.5}.get(enc, 90)
    log_ns = None if log is None else stamp_ns(log)
    w.write_image(topic, Header(stamp_ns(t), "cam"), np.full(shape, fill, dtype), enc, log_ns)


def _pairs(w: BagWriter, n: int = 3, rgb: str = RGB_TOPIC, enc: str = "rgb8") -> None:
    for i in range(n):
        _frame(w, rgb, 10 + i / 30, enc)
        _frame(w, DEPTH_TOPIC, 10 + i / 30 + 0.004, "16UC1")


def _two_colour(p: Path) -> Path:
    with _bag(p) as w:
        _pairs(w)
        _frame(w, "/other/image_raw", 11.0)
    return w.path


def _unknown_encoding(p: Path) -> Path:
    with _bag(p, ros1=False) as w:
        _pairs(w, enc="16UC3")
    return w.path


def _bad_third_frame(p: Path) -> Path:
    with _bag(p, ros1=False) as w:  # fails mid-run, after the first frames were processed
        _pairs(w, 2)
        _frame(w, RGB_TOPIC, 10.1, "yuv422")
        _frame(w, DEPTH_TOPIC, 10.104, "16UC1")
    return w.path


def _depth_only(p: Path) -> Path:
    with _bag(p) as w:
        for i in range(3):
            _frame(w, DEPTH_TOPIC, 10 + i / 30, "16UC1")
    return w.path


def _zero_info(p: Path) -> Path:
    with _bag(p, ros1=False) as w:
        w.write_camera_info("/camera/rgb/camera_info", Header(stamp_ns(10), "cam"), (64, 48),
                            (0.0, 0.0, 0.0, 0.0))  # fmt: skip
        _pairs(w)
    return w.path


def _info_of_another_size(p: Path) -> Path:
    with _bag(p) as w:
        w.write_camera_info("/camera/rgb/camera_info", Header(stamp_ns(10), "cam"), (640, 480),
                            (525.0, 525.0, 319.5, 239.5))  # fmt: skip
        _pairs(w)
    return w.path


def _backwards(p: Path) -> Path:
    with _bag(p) as w:  # log times rise, header stamps fall back at the third frame
        for i, t in enumerate((10.0, 10.033, 10.01)):
            _frame(w, RGB_TOPIC, t, log=10 + i / 30)
            _frame(w, DEPTH_TOPIC, t + 0.004, "16UC1", log=10 + i / 30 + 0.004)
    return w.path


def _compressed_bomb(p: Path) -> Path:
    """A CompressedImage whose PNG header declares 50000 x 50000 pixels (the pixel cap)."""
    bomb = png_bomb(p.with_suffix(".png")).read_bytes()
    p.with_suffix(".png").unlink()
    with _bag(p) as w:
        for i in range(2):
            w.write_compressed(RGB_TOPIC, Header(stamp_ns(10 + i / 30), "cam"), bomb, "png")
            _frame(w, DEPTH_TOPIC, 10 + i / 30 + 0.004, "16UC1")
    return w.path


def _truncated(env: Env, p: Path, name: str) -> Path:
    src = env.bags[name]
    data = src.read_bytes()
    out = p.with_name("cut" + src.suffix)
    out.write_bytes(data[: len(data) // 2])
    return out


BAD = {
    "missing topic": (lambda e, p: e.bags["raw.bag"], ["--rgb-topic", "/nope"], "no such topic"),
    "two colour topics": (lambda e, p: _two_colour(p), [], "2 candidate colour topics"),
    "unknown encoding": (lambda e, p: _unknown_encoding(p), [], "colour encoding '16UC3'"),
    "a later frame in yuv422": (lambda e, p: _bad_third_frame(p), [], "encoding 'yuv422'"),
    "truncated ROS 1": (lambda e, p: _truncated(e, p, "raw.bag"), [], "cannot read bag"),
    "truncated MCAP": (lambda e, p: _truncated(e, p, "bare.mcap"), [], "cannot read bag"),
    "depth without colour": (lambda e, p: _depth_only(p), [], "no colour image topic"),
    "camera_info of zeros": (lambda e, p: _zero_info(p), [], "uncalibrated camera"),
    "stamps backwards": (lambda e, p: _backwards(p), [], "go backwards"),
    "camera_info of another size": (lambda e, p: _info_of_another_size(p), [], "is for 640x480"),
    "a compressed frame over the pixel cap": (lambda e, p: _compressed_bomb(p), [], "50000x50000"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_bag_ends_in_one_line_exit_2_nothing_written(
    env: Env, tmp_path: Path, capsys, case: str
) -> None:
    make, extra, message = BAD[case]
    bag = make(env, tmp_path / "bad")
    for out in (tmp_path / "out", tmp_path / "new" / "out.mcap"):
        capsys.readouterr()
        assert main(env.dynamic(bag, out, *extra)) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
        assert not out.exists()
    made = [bag.name] if bag.parent == tmp_path else []  # the bad bag itself, nothing else
    assert [p.name for p in tmp_path.iterdir()] == made


def test_bag_options_on_a_folder_are_refused(env: Env, tmp_path: Path, capsys) -> None:
    assert main(env.dynamic(env.seq, tmp_path / "o", "--rgb-topic", "/x")) == 2
    assert "--rgb-topic: for a ROS bag --sequence only" in capsys.readouterr().err


def test_a_bag_without_rosbags_names_the_extra(env: Env, tmp_path: Path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "rosbags", None)
    assert main(env.dynamic(env.bags["raw.bag"], tmp_path / "o")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install 'slimseg[ros]'" in err
    assert not (tmp_path / "o").exists()


def test_an_existing_bag_output_is_never_overwritten(env: Env, tmp_path: Path, capsys) -> None:
    out = tmp_path / "masks.mcap"
    out.write_bytes(b"user data")
    assert main(env.dynamic(env.bags["raw.bag"], out)) == 2
    assert "never overwritten" in capsys.readouterr().err and out.read_bytes() == b"user data"
