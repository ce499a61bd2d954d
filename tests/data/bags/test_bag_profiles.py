"""MCAP of every profile, written by the tooling robots record with
(``tests/profile_recordings.py``: mcap-ros1-support, mcap-ros2-support, foxglove-sdk, mcap-
protobuf-support + foxglove-schemas-protobuf, the mcap package's JSON writer), reads as the TUM
folder it was made from; ``slimseg dynamic`` on each gives the folder's masks byte for byte; the
ground truth comes from their pose topics; a Foxglove source gets its masks back as Foxglove
messages at its stamps, read back with mcap-protobuf-support's own decoder; a recording of
schemas slimseg cannot decode is refused in one line within a second."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import profile_recordings as pr
import pytest
from conftest import class_map_weights

from slimseg.cli.main import main
from slimseg.data.bags.header import stamp_ns
from slimseg.data.bags.poses import read_poses
from slimseg.data.bags.sequence import BagSequence
from slimseg.data.sequence_source import open_sequence
from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence, mask_name, read_trajectory
from slimseg.sequence.mask_bag import MASK_TOPIC, MASKED_TOPIC, OBJECTS_TOPIC
from slimseg.utils.atomic import write_png

pytest.importorskip("rosbags")
pytest.importorskip("mcap_ros1")
pytest.importorskip("mcap_ros2")
pytest.importorskip("mcap_protobuf")
pytest.importorskip("foxglove")

# name → (writer, its ground-truth topic, profile slimseg reports)
RECORDINGS = {
    "ros1.mcap": (pr.write_ros1_mcap, pr.GT, "ros1"),
    "ros2.mcap": (pr.write_ros2_mcap, pr.GT, "ros2"),
    "foxglove_sdk.mcap": (pr.write_foxglove_sdk, pr.GT, "foxglove protobuf"),
    "foxglove_pb_png.mcap": (pr.write_foxglove_protobuf, pr.TF, "foxglove protobuf"),
    "foxglove_json.mcap": (pr.write_foxglove_json, pr.TF, "foxglove JSON"),
}


class Env:
    def __init__(self, root: Path) -> None:
        generate(root / "d", 0, 0, 64, 0, sequences=1, frames=10, seq_size=(160, 128),
                 progress=False)  # fmt: skip
        self.seq = root / "d" / "sequences" / "seq_000"
        for p in (self.seq / "depth").iterdir():  # whole millimetres (5 units at 5000/m)
            raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            write_png(p, (np.round(raw / 5.0) * 5).astype(np.uint16))
        self.recordings = {}
        for name, (write, _, _) in RECORDINGS.items():
            self.recordings[name] = root / "rec" / name
            self.recordings[name].parent.mkdir(exist_ok=True)
            write(self.seq, self.recordings[name])
        self.weights = class_map_weights(self.seq, root / "w.pt")
        self.folder_out = root / "folder_out"
        assert main(self.dynamic(self.seq, self.folder_out)) == 0

    def dynamic(self, seq: Path, out: Path, *extra: str) -> list[str]:
        return ["dynamic", "--model", str(self.weights), "--sequence", str(seq), "--out",
                str(out), "--set", "conf=0", "--threads", "1", "--quiet", *extra]  # fmt: skip


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Env:
    return Env(tmp_path_factory.mktemp("profiles"))


@pytest.mark.parametrize("name", list(RECORDINGS))
def test_every_profile_reads_as_the_folders_frames(env: Env, name: str) -> None:
    with TumSequence(env.seq) as tum, open_sequence(env.recordings[name]) as bag:
        assert isinstance(bag, BagSequence) and len(bag) == len(tum) == 10
        assert bag.profile == RECORDINGS[name][2]
        assert bag.camera == tum.camera and "camera_info" in bag.camera_source
        assert bag.frames.unmatched_rgb == bag.frames.unmatched_depth == 0
        for i in [*range(len(tum)), 2, 0]:  # in order (depth logged a frame late), then back
            rgb, depth, t = bag.load(i)
            ref_rgb, ref_depth, ref_t = tum.load(i)
            assert t == ref_t and np.array_equal(rgb, ref_rgb) and np.array_equal(depth, ref_depth)
        assert bag.headers[3].ns == stamp_ns(tum.frames[3][0][0])
        assert bag.headers[3].frame_id == pr.FRAME


@pytest.mark.parametrize("name", list(RECORDINGS))
def test_ground_truth_from_each_profiles_pose_topic(env: Env, name: str) -> None:
    want = read_trajectory(env.seq / "groundtruth.txt")
    got = read_poses(env.recordings[name], RECORDINGS[name][1])
    assert got.shape == want.shape and np.array_equal(got, want)


@pytest.mark.parametrize("name", list(RECORDINGS))
def test_dynamic_on_each_profile_gives_the_folders_masks(env: Env, tmp_path: Path, name: str):
    out = tmp_path / "out"
    assert main(env.dynamic(env.recordings[name], out)) == 0
    want = sorted((env.folder_out / "masks").iterdir())
    got = sorted((out / "masks").iterdir())
    assert [p.name for p in got] == [p.name for p in want] and len(want) == 10
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(got, want, strict=True))
    assert any(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).any() for p in want)  # not all empty


def test_predict_on_a_foxglove_colour_topic_as_on_the_folder(env: Env, tmp_path: Path) -> None:
    base = ["predict", "--model", str(env.weights), "--threads", "1", "--quiet"]
    assert main([*base, "--source", str(env.seq / "rgb"), "--out", str(tmp_path / "f")]) == 0
    for name in ("foxglove_pb_png.mcap", "foxglove_json.mcap"):
        out = tmp_path / name.replace(".mcap", "")
        assert main([*base, "--source", str(env.recordings[name]), "--out", str(out)]) == 0
        want = sorted((tmp_path / "f").glob("*_classes.png"))
        got = sorted(out.glob("*_classes.png"))
        assert len(want) == 10 and [p.name for p in got] == [p.name for p in want]
        assert all(a.read_bytes() == b.read_bytes() for a, b in zip(got, want, strict=True))


def test_foxglove_masks_go_back_as_foxglove_messages(env: Env, tmp_path: Path, capsys) -> None:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    out = tmp_path / "masks.mcap"
    src = env.recordings["foxglove_sdk.mcap"]
    assert main(env.dynamic(src, out, "--bag-masked-rgb", "--track")) == 0
    assert "ImageAnnotations" in capsys.readouterr().out
    ref = tmp_path / "ref"  # the folder's masks with the track stage on
    assert main(env.dynamic(env.seq, ref, "--track")) == 0
    tum = TumSequence(env.seq)
    with out.open("rb") as f:
        msgs = list(make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    by_topic: dict[str, list] = {}
    for schema, channel, message, decoded in msgs:
        by_topic.setdefault(channel.topic, []).append((schema.name, message, decoded))
    assert {t: {s for s, _, _ in v} for t, v in by_topic.items()} == {
        MASK_TOPIC: {"foxglove.RawImage"},
        MASKED_TOPIC: {"foxglove.RawImage"},
        OBJECTS_TOPIC: {"foxglove.ImageAnnotations"},
    }
    assert all(len(v) == len(tum) for v in by_topic.values())
    boxes = 0
    for i, (_, message, img) in enumerate(by_topic[MASK_TOPIC]):
        t = stamp_ns(tum.frames[i][0][0])
        assert img.timestamp.ToNanoseconds() == t == message.log_time
        assert (img.frame_id, img.encoding, img.width, img.height) == (pr.FRAME, "mono8", 160, 128)
        png = cv2.imread(str(ref / "masks" / mask_name(tum.frames[i][0][0])), 0)
        assert np.array_equal(np.frombuffer(img.data, np.uint8).reshape(128, 160), png)
        _, ann_message, ann = by_topic[OBJECTS_TOPIC][i]
        assert ann_message.log_time == t and len(ann.points) == len(ann.texts)
        assert all(len(p.points) == 4 and p.timestamp.ToNanoseconds() == t for p in ann.points)
        assert all(" p " in x.text for x in ann.texts)
        boxes += len(ann.points)
    assert boxes > 0
    assert any(x.text.startswith("#") for _, _, a in by_topic[OBJECTS_TOPIC] for x in a.texts)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["masks.mcap", "ref"]  # no staging


def test_a_ros_profile_source_keeps_ros_masks(env: Env, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    out = tmp_path / "masks.mcap"
    assert main(env.dynamic(env.recordings["ros1.mcap"], out)) == 0
    with out.open("rb") as f:
        names = {s.name for s, _, _ in make_reader(f).iter_messages()}
    assert names == {"sensor_msgs/msg/Image"}


def test_undecodable_schemas_refused_in_one_line_within_a_second(
    env: Env, tmp_path: Path, capsys
) -> None:
    bad = tmp_path / "flat.mcap"
    pr.write_unsupported(bad)
    start = time.perf_counter()
    assert main(env.dynamic(bad, tmp_path / "out")) == 2
    took = time.perf_counter() - start
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and took < 1.0, (err, took)
    assert "foxglove.RawImage (flatbuffer)" in err and "slimseg reads ros1msg" in err
    assert "damaged" not in err and not (tmp_path / "out").exists()


@pytest.mark.parametrize("name", ["ros1.mcap", "foxglove_sdk.mcap", "foxglove_json.mcap"])
def test_a_truncated_recording_of_any_profile_is_named_damaged(
    env: Env, tmp_path: Path, capsys, name: str
) -> None:
    data = env.recordings[name].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    assert main(env.dynamic(cut, tmp_path / "out")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot read bag" in err and "truncated or damaged" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap"]


def test_topic_listings_name_the_schemas_as_held(env: Env, tmp_path: Path, capsys) -> None:
    src = env.recordings["foxglove_sdk.mcap"]
    assert main(env.dynamic(src, tmp_path / "out", "--rgb-topic", "/nope")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "/nope: bag" in err and "no such topic" in err
    assert f"{pr.RGB} (foxglove.RawImage (protobuf))" in err
    assert f"{pr.INFO} (foxglove.CameraCalibration (protobuf))" in err
    assert main(env.dynamic(src, tmp_path / "out", "--rgb-topic", pr.GT)) == 2
    assert "carries foxglove.PoseInFrame (protobuf), expected" in capsys.readouterr().err
