"""Every resource bounded before it is spent (issue 47, class 2): thread counts, YAML, inputs
that are not regular files, kernel and export sizes; and damaged MCAP recordings refused."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from slimseg.cli.main import main
from slimseg.data.images import decode_file
from slimseg.data.tum import read_camera, read_list
from slimseg.dynamic.seg_box import dilate, dilate_masks
from slimseg.errors import SlimsegError
from slimseg.utils.input_files import check_regular, read_capped
from slimseg.utils.threads import available_cpus, check_threads, torch_threads
from slimseg.utils.yaml_io import load_yaml_text, read_yaml

BOMB = "\n".join(
    ["a: &a [x, x, x, x, x, x, x, x, x]"]
    + [f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join([f'*{chr(97 + i)}'] * 9)}]" for i in range(8)]
    + ["fx: *i", "fy: 1", "cx: 1", "cy: 1"]
)  # 9 ** 9 values once expanded, in ~400 bytes


def _one_line(capfd: pytest.CaptureFixture[str], *words: str) -> str:
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    for w in words:
        assert w in err[0], err[0]
    return err[0]


def test_thread_counts_above_the_cores_are_refused(capfd) -> None:
    cpus = available_cpus()
    assert check_threads(None) is None and check_threads(0) == 0 and check_threads(cpus) == cpus
    for bad in (cpus + 1, 10000, -1, True):
        with pytest.raises(SlimsegError, match=f"from 1 to {cpus}"):
            check_threads(bad, "threads")
    with pytest.raises(SlimsegError), torch_threads(cpus + 1):
        pass
    with pytest.raises(SystemExit) as exc:
        main(["dynamic", "--sequence", "s", "--model", "m.onnx", "--threads", "10000"])
    assert exc.value.code == 2
    _one_line(capfd, "--threads", "10000", f"0..{cpus}")


def test_alias_bombs_are_refused_before_they_expand(tmp_path: Path) -> None:
    with pytest.raises(SlimsegError, match="once its aliases are expanded"):
        load_yaml_text(BOMB, "camera.yaml")
    cam = tmp_path / "camera.yaml"
    cam.write_text(BOMB)
    with pytest.raises(SlimsegError, match=r"camera\.yaml.*aliases"):
        read_camera(cam)
    with pytest.raises(SlimsegError, match="contains it"):
        load_yaml_text("a: &a [1, *a]", "x.yaml")
    assert load_yaml_text("a: &a [1, 2]\nb: *a", "x.yaml") == {"a": [1, 2], "b": [1, 2]}
    assert load_yaml_text("", "x.yaml") is None
    with pytest.raises(SlimsegError, match="unpaired UTF-16 surrogate"):
        load_yaml_text('path: "\\ud800"', "x.yaml")
    with pytest.raises(SlimsegError, match=r"x\.yaml"):
        load_yaml_text("[" * 5000, "x.yaml")  # deeply nested: one line, not a RecursionError


def test_yaml_size_cap(tmp_path: Path, monkeypatch) -> None:
    big = tmp_path / "big.yaml"
    big.write_text("a: 1\n" * 100)
    monkeypatch.setattr("slimseg.utils.yaml_io.MAX_YAML_BYTES", 64)
    with pytest.raises(SlimsegError, match="500 bytes, over the 64-byte limit"):
        read_yaml(big, "data config")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="FIFOs need a POSIX system")
def test_fifos_and_devices_are_never_opened(tmp_path: Path, capfd) -> None:
    fifo = tmp_path / "f.yaml"
    os.mkfifo(fifo)  # opening it would block this test forever
    with pytest.raises(SlimsegError, match=r"f\.yaml: the data config is a FIFO"):
        read_yaml(fifo, "data config")
    with pytest.raises(SlimsegError, match="character device"):
        read_capped("/dev/zero", "list", 1 << 20)
    assert decode_file(fifo, 0) is None  # an image reader: unreadable, not a hang
    check_regular(__file__)
    seq = tmp_path / "seq"
    seq.mkdir()
    os.mkfifo(seq / "rgb.txt")
    os.mkfifo(seq / "x.mcap")
    (seq / "z.bag").symlink_to("/dev/zero")
    with pytest.raises(SlimsegError, match=r"rgb\.txt: the list is a FIFO"):
        read_list(seq / "rgb.txt")
    for bag in ("x.mcap", "z.bag"):
        assert main(["data", "bag2tum", "--bag", str(seq / bag), "--out", str(tmp_path / bag)]) == 2
        _one_line(capfd, bag, "not a regular file")


def test_dilation_is_bounded_and_unchanged_by_the_bound() -> None:
    mask = np.zeros((48, 64), bool)
    mask[10, 20] = True
    full = dilate(mask, 10**6)  # the kernel would be 2e6 px wide: clamped to 112
    assert full.all() and (dilate(mask, 112) == full).all()
    masks = np.stack([mask, np.zeros_like(mask)])
    assert (dilate_masks(masks, 10**6)[0] == full).all() and not dilate_masks(masks, 10**6)[1].any()
    assert (dilate(mask, 5) == dilate_masks(masks, 5)[0]).all()


@pytest.mark.parametrize("imgsz", [["0"], ["65536"], ["64", "64", "64"]])
def test_export_sizes_are_refused_in_one_line(imgsz: list[str], tmp_path: Path, capfd) -> None:
    argv = ["export", "--weights", "yolov8n-seg", "--out", str(tmp_path / "m.onnx")]
    try:
        code = main([*argv, "--imgsz", *imgsz])
    except SystemExit as e:
        code = e.code
    assert code == 2 and not (tmp_path / "m.onnx").exists()
    _one_line(capfd, "--imgsz")


def test_mcap_checksums_written_and_checked(tmp_path: Path, capfd) -> None:
    pytest.importorskip("rosbags")
    seq = tmp_path / "ds"
    argv = ["data", "synth", "--out", str(seq), "--train", "0", "--val", "0", "--sequences", "1"]
    assert main([*argv, "--frames", "3", "--seq-size", "64", "64"]) == 0
    bag = tmp_path / "s.mcap"
    assert (
        main(["data", "tum2bag", "--sequence", str(seq / "sequences/seq_000"), "--out", str(bag)])
        == 0
    )
    assert main(["data", "bag2tum", "--bag", str(bag), "--out", str(tmp_path / "back")]) == 0
    data = bytearray(bag.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 2048] = np.random.default_rng(0).integers(0, 256, 2048, np.uint8).tobytes()
    damaged = tmp_path / "d.mcap"
    damaged.write_bytes(bytes(data))
    capfd.readouterr()
    assert main(["data", "bag2tum", "--bag", str(damaged), "--out", str(tmp_path / "d")]) == 2
    _one_line(capfd, "d.mcap", "checksum")
    assert not (tmp_path / "d").exists()
    shutil.rmtree(tmp_path / "back")
