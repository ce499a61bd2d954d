"""``slimseg ablate``: config validation, the report against the paper, and a sweep killed
after its first variant that resumes (first row kept, second variant from its checkpoint)."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from slimseg.ablate.config import load_ablation_config
from slimseg.ablate.paper_table import paper_key
from slimseg.ablate.report import markdown, write_reports
from slimseg.ablate.sweep import prepare_sweep_dir, run_sweep
from slimseg.cli.main import main
from slimseg.errors import SlimsegError
from slimseg.utils.shipped import shipped_dir

ABLATION_DIR = shipped_dir("ablation")
RECIPE = shipped_dir("train") / "cpu-demo.yaml"


def tiny_config(tmp_path: Path, epochs: int = 4, **extra: str) -> Path:
    text = f"""
name: tiny
variants: [yolov8n-seg, yolov8n-seg-gs-rep]
data: synth
synth: {{train_images: 48, val_images: 4, imgsz: 64, seed: 0}}
train: {{recipe: {RECIPE}, epochs: {epochs}, imgsz: 64, batch: 8, val_every: {epochs}, threads: 1}}
bench: {{runs: 2, warmup: 1, threads: 1}}
gflops_imgsz: 64
"""
    for key, value in extra.items():
        text += f"{key}: {value}\n"
    path = tmp_path / "tiny.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", ["table2-synth", "table2-coco20"])
def test_shipped_configs_load(name: str) -> None:
    path = ABLATION_DIR / f"{name}.yaml"
    if name == "table2-coco20":  # points at the user's COCO-20 build: pass a stand-in
        cfg = load_ablation_config(path, data=str(RECIPE))
        first = cfg.variants[0].name
        assert (cfg.train.epochs, cfg.train.imgsz, first) == (500, 640, "yolov8s-seg")
    else:
        cfg = load_ablation_config(path)
        assert cfg.data_path is None and len(cfg.variants) == 4
        assert all(a.name.startswith("yolov8n-seg") for a in cfg.variants)
    names = [a.name for a in cfg.variants]
    assert all(a.plain for a in cfg.variants)
    assert [paper_key(v) for v in names] == [
        "yolov8s-seg" + v.removeprefix("yolov8n-seg").removeprefix("yolov8s-seg") for v in names
    ]
    # no arms, seeds, metrics or bench sizes: the hash input is what it was before they existed
    d = cfg.to_dict()
    assert d["variants"] == names and not {"seeds", "metrics"} & set(d)
    assert sorted(d["bench"]) == ["runs", "threads", "warmup"]
    assert cfg.run_seeds == (cfg.train.seed,) and cfg.bench_sizes == (cfg.train.imgsz,)


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        ({"colour": "red"}, "unknown field(s) ['colour']"),
        ({"variants": "[yolov8q-seg]"}, "variants ['yolov8q-seg'] unknown; valid:"),
        ({"data": "missing.yaml"}, "does not exist; build it"),
        ({"gflops_imgsz": "'big'"}, "gflops_imgsz: expected int"),
    ],
)
def test_bad_configs_name_the_field(tmp_path: Path, edit: dict, needle: str) -> None:
    path = tiny_config(tmp_path)
    text = path.read_text()
    for key, value in edit.items():
        lines = [line for line in text.splitlines() if not line.startswith(f"{key}:")]
        text = "\n".join([*lines, f"{key}: {value}"])
    path.write_text(text)
    with pytest.raises(SlimsegError) as err:
        load_ablation_config(path)
    assert needle in str(err.value) and str(path) in str(err.value)


def test_unknown_train_field_and_missing_recipe(tmp_path: Path) -> None:
    path = tiny_config(tmp_path)
    path.write_text(path.read_text().replace("threads: 1", "threads: 1, lr00: 1"))
    with pytest.raises(SlimsegError, match=r"train: unknown field\(s\) \['lr00'\]"):
        load_ablation_config(path)
    path.write_text(path.read_text().replace(str(RECIPE), "nowhere.yaml"))
    with pytest.raises(SlimsegError, match=r"train.recipe .*nowhere.yaml does not exist"):
        load_ablation_config(path)


def test_sweep_folder_of_another_config_is_refused(tmp_path: Path) -> None:
    cfg = load_ablation_config(tiny_config(tmp_path, epochs=4))
    prepare_sweep_dir(cfg, tmp_path / "out")
    prepare_sweep_dir(cfg, tmp_path / "out")  # same config: fine
    other = load_ablation_config(tiny_config(tmp_path, epochs=5))
    with pytest.raises(SlimsegError, match="holds a sweep of another config"):
        prepare_sweep_dir(other, tmp_path / "out")


def _row(variant: str, box: float, seg: float, gflops_paper: float, params_paper: int) -> dict:
    return {
        "variant": variant,
        "model": variant,
        "epochs": 9,
        "best_epoch": 9,
        "box_map50_95": box,
        "seg_map50_95": seg,
        "box_map50": 2 * box,
        "seg_map50": 2 * seg,
        "gflops": gflops_paper - 0.5,
        "gflops_paper": gflops_paper,
        "gflops_imgsz": 640,
        "gradients": params_paper - 16,
        "params": params_paper,
        "params_paper": params_paper,
        "fused_params": params_paper - 1000,
        "latency_ms": 10.0,
        "latency_imgsz": 256,
        "ms_net@256": 10.0,
        "train_img_s": 20.0,
        "val_images": 96,
        "num_classes": 6,
        "spec_hash": "0" * 12,
        "git_sha": "abc",
        "seed": 0,
    }


def test_report_compares_changes_against_each_baseline(tmp_path: Path) -> None:
    cfg = load_ablation_config(ABLATION_DIR / "table2-synth.yaml")
    rows = [
        _row("yolov8n-seg", 0.100, 0.080, 12.0, 3_000_000),
        _row("yolov8n-seg-gs-rep", 0.110, 0.075, 9.0, 2_400_000),
    ]
    text = markdown(rows, cfg)
    # ours: +1.0 box points, -0.5 seg points, -25 % GFLOPs, -20 % params
    # paper: 46.8-46.2 = +0.6, 40.3-39.5 = +0.8, 37.4/42.7-1 = -12.4 %, 10.2/11.8-1 = -13.6 %
    line = next(x for x in text.splitlines() if x.startswith("| yolov8n-seg-gs-rep | +"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells == [
        "yolov8n-seg-gs-rep",
        "+1.0",
        "+0.6",
        "-0.5",
        "+0.8",
        "-25.0 %",
        "-12.4 %",
        "-20.0 %",
        "-13.6 %",
    ]
    assert "| yolov8n-seg-gs-rep → yolov8s-seg-gs-rep | 11.0 | 46.8 | 7.5 | 40.3 |" in text
    csv_path, md_path, png_path, _ = write_reports(rows, tmp_path, cfg)
    with csv_path.open() as f:
        assert [r["variant"] for r in csv.DictReader(f)] == ["yolov8n-seg", "yolov8n-seg-gs-rep"]
    assert md_path.read_text() == text
    assert png_path.stat().st_size > 10_000
    assert not list(tmp_path.glob(".*tmp*"))


@pytest.mark.slow
def test_killed_sweep_resumes_keeping_finished_rows(tmp_path: Path) -> None:
    config, out = tiny_config(tmp_path), tmp_path / "sweep"
    first, second = out / "variants" / "yolov8n-seg", out / "variants" / "yolov8n-seg-gs-rep"
    argv = [sys.executable, "-m", "slimseg", "ablate", "--config", str(config)]
    argv += ["--out", str(out), "--quiet"]
    env = os.environ | {"OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 600
    while not (second / "checkpoints" / "last.ckpt").is_file():
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        assert time.monotonic() < deadline, "sweep did not reach the second variant"
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)  # mid-second variant: after its first of 4 epochs
    proc.wait()
    assert (first / "row.json").is_file() and not (second / "row.json").exists()
    assert not (out / "results.md").read_text().count("yolov8n-seg-gs-rep |")
    kept = (first / "row.json").read_bytes()
    kept_mtime = (first / "row.json").stat().st_mtime_ns

    log = tmp_path / "log.txt"
    with log.open("w") as f:
        done = subprocess.run(argv, env=env, stdout=f, stderr=subprocess.STDOUT, check=False)
    text = log.read_text()
    assert done.returncode == 0, text[-3000:]
    assert "yolov8n-seg: done earlier, row kept" in text
    assert "yolov8n-seg-gs-rep: resuming after epoch 1" in text
    assert (first / "row.json").read_bytes() == kept
    assert (first / "row.json").stat().st_mtime_ns == kept_mtime
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["variant"] for r in rows] == ["yolov8n-seg", "yolov8n-seg-gs-rep"]
    row = json.loads((second / "row.json").read_text())
    assert row["epochs"] == 4 and row["best_epoch"] == 4
    # nc 6 (the synth classes): 2,377,047 at nc 20 minus 14 x 65 (one shared 1x1 cls row each)
    assert row["params"] == 2_376_137
    epochs = json.loads((second / "throughput.json").read_text())["epochs"]
    assert sorted(epochs) == ["0", "1", "2", "3"]  # the killed run's epoch 0, three resumed
    assert all(n == 48 for n, _ in epochs.values())
    assert row["train_img_s"] > 0 and math.isfinite(row["latency_ms"])
    assert (second / "model.onnx").is_file() and (out / "results.png").is_file()
    # the finished sweep rerun trains nothing
    assert main(["ablate", "--config", str(config), "--out", str(out), "--quiet"]) == 0


def test_bad_data_config_fails_before_writing(tmp_path: Path) -> None:
    data = tmp_path / "data.yaml"
    data.write_text("path: nowhere\ntrain: {images: a, annotations: a.json}\n")
    cfg = load_ablation_config(tiny_config(tmp_path), data=str(data))
    with pytest.raises(SlimsegError, match="nowhere"):
        run_sweep(cfg, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()
