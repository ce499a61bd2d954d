"""Issue #62's limits outside the recordings: every size bounded before it is spent
(``export --end2end`` refuses a ``--max-det`` / ``--imgsz`` whose masks would pass 1 GiB before
a model is built), every source a regular file (``predict --source`` on a FIFO named like a
video or a list is refused instead of blocking forever), ``data show`` never replacing a file of
the dataset nor reading outside it, and every print of the CLI escaped (an output path too)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from slimseg.cli.export import END2END_MASK_BYTES, check_end2end_size
from slimseg.cli.main import main
from slimseg.data.frame_files import open_source
from slimseg.errors import SlimsegError


@pytest.mark.parametrize(
    ("max_det", "imgsz"), [(1_000_000_000, ["160"]), (300, ["4096"]), (20_000, ["640", "640"])]
)
def test_end2end_sizes_past_the_budget_are_refused_before_building(
    tmp_path: Path, capsys, max_det: int, imgsz: list[str]
) -> None:
    out = tmp_path / "e.onnx"
    start = time.perf_counter()
    code = main(["export", "--weights", "yolov8n-seg", "--nc", "3", "--imgsz", *imgsz,
                 "--end2end", "--max-det", str(max_det), "--quiet", "--out", str(out)])  # fmt: skip
    took = time.perf_counter() - start
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "GiB" in err and "--max-det" in err, err
    assert took < 10 and not out.exists() and list(tmp_path.iterdir()) == []


def test_the_end2end_budget_is_exact() -> None:
    cells = (640 // 4) * (640 // 4)
    most = END2END_MASK_BYTES // (cells * 4)
    check_end2end_size(most, [640, 640])  # at the budget: accepted
    with pytest.raises(SlimsegError, match=f"give --max-det {most} or less"):
        check_end2end_size(most + 1, [640])
    check_end2end_size(300, [2048])  # the default max-det up to 2048 px


@pytest.mark.parametrize("name", ["fifo.mp4", "fifo.txt", "fifo.png"])
def test_a_fifo_source_is_refused_not_opened(tmp_path: Path, name: str) -> None:
    fifo = tmp_path / name
    os.mkfifo(fifo)
    with pytest.raises(SlimsegError, match="FIFO"):
        open_source(fifo)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from slimseg.data.synth import generate

    root = tmp_path_factory.mktemp("show") / "d"
    generate(root, 2, 2, 64, 0, progress=False)
    return root


def test_data_show_never_replaces_an_image_of_the_other_split(dataset: Path, capsys) -> None:
    image = sorted((dataset / "val").rglob("*.png"))[0]
    before = image.read_bytes()
    code = main(["data", "show", "--data", str(dataset / "data.yaml"), "--imgsz", "64",
                 "--count", "1", "--out", str(image)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "lies in the dataset's val folder" in err, err
    assert image.read_bytes() == before


def test_data_show_refuses_a_file_name_climbing_out(dataset: Path, tmp_path: Path, capsys):
    import json
    import shutil

    copy = tmp_path / "d"
    shutil.copytree(dataset, copy)
    ann = next((copy / "train").rglob("*.json"))
    data = json.loads(ann.read_text())
    data["images"][0]["file_name"] = "../../../outside.png"
    ann.write_text(json.dumps(data))
    out = tmp_path / "show.png"
    code = main(["data", "show", "--data", str(copy / "data.yaml"), "--imgsz", "64", "--count",
                 "1", "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "outside the images folder" in err, err
    assert "../../../outside.png" in err and not out.exists()


def test_an_output_path_with_escape_codes_is_printed_escaped(tmp_path: Path, capfd) -> None:
    """Any print of the CLI goes through one escaping stream: bag2tum's --out here."""
    import hostile_recordings as hr

    pytest.importorskip("mcap_protobuf")
    bag = hr.protobuf_recording(tmp_path / "ok.mcap")
    out = tmp_path / "o\x1b[2J\x1b[31mx"
    assert main(["data", "bag2tum", "--bag", str(bag), "--out", str(out), "--quiet"]) == 0
    printed = capfd.readouterr().out
    assert "\x1b" not in printed and "o\\x1b[2J\\x1b[31mx" in printed, printed
    assert (out / "rgb.txt").is_file()
