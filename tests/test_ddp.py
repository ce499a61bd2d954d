"""Lightning DDP on CPU (gloo, 2 processes): training runs and both ranks hold the same model.

Lightning's DDP launcher starts rank 1 by re-running rank 0's command line, so training is
driven either by the CLI (``python -m slimseg train --devices 2``) or by a small script written
into a temp folder and run as ``python script.py``. After ``train()`` returns, the script makes
each rank write per-tensor sums of its model and EMA to ``rank{R}.json``: DDP keeps the
parameters identical on every rank, so the sums must agree.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from slimseg.data.synth import generate

pytestmark = pytest.mark.slow

SCRIPT = textwrap.dedent(
    """
    import json
    import sys
    from pathlib import Path

    from slimseg.engine.config import load_train_config
    from slimseg.engine.train import train


    def sums(tensors):
        return {k: float(v.detach().double().sum()) for k, v in tensors if v.is_floating_point()}


    if __name__ == "__main__":
        data, recipe, out, report = sys.argv[1:5]
        module, run = train(
            "yolov8n-seg",
            data,
            load_train_config(recipe),
            Path(out),
            devices=2,
            accelerator="cpu",
            progress=False,
        )
        trainer = module.trainer
        ema = module.ema.module if module.ema is not None else None
        result = {
            "rank": trainer.global_rank,
            "world_size": trainer.world_size,
            "strategy": type(trainer.strategy).__name__,
            "run": str(run),
            "steps": trainer.global_step,
            "params": sums(module.model.named_parameters()),
            "buffers": sums(module.model.named_buffers()),
            "ema_params": sums(ema.named_parameters()) if ema is not None else {},
            "ema_buffers": sums(ema.named_buffers()) if ema is not None else {},
        }
        path = Path(report) / f"rank{trainer.global_rank}.json"
        path.write_text(json.dumps(result))
    """
)

# 16 train images / (2 ranks x batch 4) = 2 steps per epoch
RECIPE = """\
epochs: 2
batch: 4
imgsz: 96
optimizer: adamw
lr0: 0.002
warmup_epochs: 0.0
warmup_bias_lr: 0.0
close_mosaic: 1
ema: true
ema_decay: 0.999
amp: false
seed: 0
workers: 0
threads: 1
"""


def _env() -> dict[str, str]:
    """The current environment without DDP variables, with a free MASTER_PORT."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("LOCAL_RANK", "NODE_RANK", "GLOBAL_RANK", "RANK", "WORLD_SIZE")
    }
    env.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), OMP_NUM_THREADS="1")
    return env


def _run(cmd: list[str], cwd: Path) -> subprocess.CompletedProcess:
    proc = subprocess.run(
        cmd, cwd=cwd, env=_env(), capture_output=True, text=True, timeout=600, check=False
    )
    assert proc.returncode == 0, f"{' '.join(cmd)} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc


def _differ(a: dict[str, float], b: dict[str, float], rel: float = 1e-6) -> list[str]:
    assert a and a.keys() == b.keys()
    return [k for k in a if abs(a[k] - b[k]) > rel * max(abs(a[k]), abs(b[k]), 1.0)]


@pytest.fixture(scope="module")
def data_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("ddp-data")
    (root / "recipe.yaml").write_text(RECIPE)
    return generate(root / "data", train=16, val=4, imgsz=96, seed=0, progress=False).data_yaml


@pytest.fixture(scope="module")
def ddp_script_run(tmp_path_factory: pytest.TempPathFactory, data_yaml: Path) -> dict:
    """One DDP training through ``train()``; the per-rank reports and the work folder."""
    work = tmp_path_factory.mktemp("ddp-script")
    script = work / "ddp_train.py"
    script.write_text(SCRIPT)
    recipe = data_yaml.parent.parent / "recipe.yaml"
    report = work / "report"
    report.mkdir()
    cmd = [sys.executable, str(script), str(data_yaml), str(recipe), str(work / "run"), str(report)]
    _run(cmd, work)
    ranks = [json.loads((report / f"rank{r}.json").read_text()) for r in (0, 1)]
    return {"work": work, "ranks": ranks}


def test_ddp_script_trains_on_two_ranks(ddp_script_run: dict) -> None:
    r0, r1 = ddp_script_run["ranks"]
    assert (r0["rank"], r1["rank"]) == (0, 1)
    assert r0["world_size"] == r1["world_size"] == 2
    assert r0["strategy"] == r1["strategy"] == "DDPStrategy"
    assert r0["steps"] == r1["steps"] == 4
    run = Path(r0["run"])
    assert run == ddp_script_run["work"] / "run"
    for name in ("weights/last.pt", "weights/best.pt", "checkpoints/last.ckpt"):
        assert (run / name).is_file(), name
    assert len((run / "results.csv").read_text().strip().splitlines()) == 1 + 2


def test_ddp_parameters_identical_across_ranks(ddp_script_run: dict) -> None:
    r0, r1 = ddp_script_run["ranks"]
    for key in ("params", "buffers", "ema_params"):
        diff = _differ(r0[key], r1[key])
        assert not diff, f"{key} differ across ranks: {diff[:5]}"


def test_ddp_ema_buffers_identical_across_ranks(ddp_script_run: dict) -> None:
    r0, r1 = ddp_script_run["ranks"]
    diff = _differ(r0["ema_buffers"], r1["ema_buffers"])
    assert not diff, f"EMA buffers differ across ranks: {diff[:5]}"


def test_ddp_single_run_folder(ddp_script_run: dict) -> None:
    r0, r1 = ddp_script_run["ranks"]
    assert r1["run"] == r0["run"]
    assert not (ddp_script_run["work"] / "run-2").exists()


def test_ddp_cli(tmp_path: Path, data_yaml: Path) -> None:
    out = tmp_path / "run"
    cmd = [
        sys.executable,
        "-m",
        "slimseg",
        "train",
        "--model",
        "yolov8n-seg",
        "--data",
        str(data_yaml),
        "--config",
        str(data_yaml.parent.parent / "recipe.yaml"),
        "--epochs",
        "1",
        "--workers",
        "0",
        "--accelerator",
        "cpu",
        "--devices",
        "2",
        "--out",
        str(out),
        "--quiet",
    ]
    proc = _run(cmd, tmp_path)
    assert proc.stdout.count("run folder:") == 1  # rank 0 only
    for name in ("weights/last.pt", "weights/best.pt", "checkpoints/last.ckpt", "results.csv"):
        assert (out / name).is_file(), name
