"""``slimseg ablate --backend ray`` on a loopback Ray cluster (a head without CPUs, two worker
nodes of one CPU each, all on 127.0.0.1): rows equal to the local backend's, a worker node
killed mid-run, the driver killed and started again. Tiny runs (16 images of 64 px, 3
epochs); the reference sweep runs on the local backend in a process that never imports Ray.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from progress_wait import wait_process, wait_until

from slimseg.ablate.lease import read_attempts, state_dir
from slimseg.ablate.rows import timing_keys
from slimseg.utils.shipped import shipped_dir

ray = pytest.importorskip("ray")
from ray.cluster_utils import Cluster  # noqa: E402

pytestmark = pytest.mark.slow

RECIPE = shipped_dir("train") / "cpu-demo.yaml"
ARMS = ("yolov8n-seg", "yolov8n-seg-gs")
EPOCHS = 3
# Ray on loopback (docs: /work/shared/research/distributed_sweeps.md): every address is
# 127.0.0.1 (this variable makes Ray keep the loopback address), no token to hand around.
RAY_ENV = {
    "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
    "RAY_AUTH_MODE": "disabled",
    "OMP_NUM_THREADS": "1",
}
FAST_HEALTH = {
    "health_check_period_ms": 500,
    "health_check_failure_threshold": 3,
    "health_check_timeout_ms": 500,
}
NODE = {"node_ip_address": "127.0.0.1", "object_store_memory": 80 * 1024**2}
# Waits end when a run stops making progress (nothing written under its sweep folder or to its
# log for progress_wait.STALL_S), never at a fixed time: a loaded CI machine is slower, not
# stuck.


def write_config(folder: Path) -> Path:
    path = folder / "tiny-ray.yaml"
    path.write_text(
        f"""name: tiny-ray
variants: [{", ".join(ARMS)}]
data: synth
synth: {{train_images: 16, val_images: 4, imgsz: 64, seed: 0}}
train: {{recipe: {RECIPE}, epochs: {EPOCHS}, imgsz: 64, batch: 8, val_every: {EPOCHS},
         threads: 1}}
bench: {{runs: 2, warmup: 1, threads: 1}}
gflops_imgsz: 64
"""
    )
    return path


@pytest.fixture(scope="module")
def ray_env() -> Iterator[None]:
    with pytest.MonkeyPatch.context() as mp:
        for key, value in RAY_ENV.items():
            mp.setenv(key, value)
        yield


@pytest.fixture(scope="module")
def cluster(ray_env: None) -> Iterator[Cluster]:
    c = Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 0, "include_dashboard": False, **NODE}
        | {"_system_config": FAST_HEALTH},
    )
    for _ in range(2):
        c.add_node(num_cpus=1, **NODE)
    c.wait_for_nodes()
    yield c
    c.shutdown()


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("ray-sweeps")


@pytest.fixture(scope="module")
def reference(folder: Path, ray_env: None) -> Path:
    """The sweep on the local backend, in a process that must never import Ray."""
    out = folder / "local"
    code = (
        "import sys; from slimseg.cli.main import main; "
        f"rc = main(['ablate', '--config', {str(write_config(folder))!r}, '--out', "
        f"{str(out)!r}, '--quiet']); "
        "assert 'ray' not in sys.modules, 'a local sweep imported ray'; sys.exit(rc)"
    )
    log = folder / "local.log"
    with log.open("w") as f:
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=f, stderr=subprocess.STDOUT)
    assert wait_process(proc, [out, log], "the local sweep", log) == 0, log.read_text()[-3000:]
    return out


def driver_argv(folder: Path, out: Path, address: str) -> list[str]:
    argv = ["ablate", "--config", str(write_config(folder)), "--out", str(out), "--quiet"]
    return [*argv, "--backend", "ray", "--address", address, "--throughput-steps", "2"]


def start_driver(folder: Path, out: Path, address: str, log: Path) -> subprocess.Popen:
    """The driver as its own process: Ray reads RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER when it is
    imported, which in this process happened before the fixture could set it."""
    argv = [sys.executable, "-m", "slimseg", *driver_argv(folder, out, address)]
    with log.open("a") as f:
        return subprocess.Popen(argv, stdout=f, stderr=subprocess.STDOUT)


def run_driver(folder: Path, out: Path, address: str, log: Path) -> str:
    """A driver run to its end (exit 0); returns what it printed this time."""
    before = log.stat().st_size if log.exists() else 0
    proc = start_driver(folder, out, address, log)
    assert wait_process(proc, [out, log], "the driver", log) == 0, log.read_text()[-3000:]
    return log.read_text()[before:]


# Not compared: the timing columns (machine-dependent) and the git commit, which moves when
# the checkout gets a commit between the reference sweep and the one compared with it.
SKIP = {*timing_keys((64,), False), "train_img_s_from", "git_sha"}


def deterministic(out: Path) -> list[dict]:
    """Each run's row without the machine-dependent columns."""
    skip = SKIP
    rows = []
    for arm in ARMS:
        row = json.loads((out / "variants" / arm / "row.json").read_text())
        rows.append({k: v for k, v in row.items() if k not in skip})
    return rows


def assert_same_sweep(out: Path, reference: Path) -> None:
    """Rows, results.csv (machine-dependent columns aside) and trained weights equal."""
    assert deterministic(out) == deterministic(reference)
    for arm in ARMS:
        a = torch.load(out / "variants" / arm / "weights" / "best.pt", weights_only=False)
        b = torch.load(reference / "variants" / arm / "weights" / "best.pt", weights_only=False)
        sa, sb = a["state_dict"], b["state_dict"]
        assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa), arm
    skip = SKIP
    for path in (out / "results.csv", reference / "results.csv"):
        assert path.is_file()
    with (out / "results.csv").open() as f, (reference / "results.csv").open() as g:
        ours, theirs = list(csv.DictReader(f)), list(csv.DictReader(g))
    assert [{k: v for k, v in r.items() if k not in skip} for r in ours] == [
        {k: v for k, v in r.items() if k not in skip} for r in theirs
    ]


def train_attempts(out: Path, arm: str) -> list[dict]:
    return [r for r in read_attempts(state_dir(out, arm)) if r["stage"] == "train"]


def test_ray_rows_equal_local(cluster: Cluster, reference: Path, folder: Path) -> None:
    out = folder / "ray"
    text = run_driver(folder, out, cluster.address, folder / "ray.log")
    assert "2 node(s) can take a run" in text and "progress: 2 done" in text
    assert_same_sweep(out, reference)
    row = json.loads((out / "variants" / ARMS[0] / "row.json").read_text())
    assert row["train_img_s_from"] == "steps" and row["train_img_s"] > 0
    assert len({train_attempts(out, a)[0]["node"] for a in ARMS}) == 2  # one run per node
    assert not list(out.glob(".shared-probe-*"))


def test_worker_node_killed_mid_run(cluster: Cluster, reference: Path, folder: Path) -> None:
    out, log = folder / "node-killed", folder / "node-killed.log"
    proc = start_driver(folder, out, cluster.address, log)
    ckpts = [out / "variants" / a / "checkpoints" / "last.ckpt" for a in ARMS]
    wait_until(lambda: any(p.is_file() for p in ckpts), [out, log], "a first checkpoint", proc, log)
    arm = ARMS[[p.is_file() for p in ckpts].index(True)]
    node_id = train_attempts(out, arm)[-1]["node"].split("/")[1]
    victim = next(n for n in cluster.worker_nodes if n.node_id.startswith(node_id))
    cluster.remove_node(victim, allow_graceful=False)
    try:
        assert wait_process(proc, [out, log], "the driver", log) == 0, log.read_text()[-3000:]
    finally:
        cluster.add_node(num_cpus=1, **NODE)  # the next test gets two workers again
    text = log.read_text()
    first, retry = train_attempts(out, arm)
    assert "finished" not in first and first["node"] != retry["node"]
    assert retry["resumed_from"] >= 1 and retry["outcome"] == "done"
    assert f"{arm}: retried on {retry['node']} (attempt 2)" in text, text
    assert "1 retried" in text
    assert_same_sweep(out, reference)


def test_driver_killed_and_started_again(cluster: Cluster, reference: Path, folder: Path) -> None:
    out, log = folder / "driver-killed", folder / "driver-killed.log"
    proc = start_driver(folder, out, cluster.address, log)
    runs = [out / "variants" / a for a in ARMS]
    wait_until(
        lambda: any((r / "checkpoints" / "last.ckpt").is_file() for r in runs),
        [out, log],
        "a run past its first epoch",
        proc,
        log,
    )
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    cut = [a for a, r in zip(ARMS, runs, strict=True) if not (r / "scores.json").exists()]
    cut_mid_run = [a for a in cut if (out / "variants" / a / "checkpoints" / "last.ckpt").exists()]
    assert cut_mid_run
    run_driver(folder, out, cluster.address, log)
    for arm in cut_mid_run:  # the new driver's attempt went on from the checkpoint
        assert len(train_attempts(out, arm)) == 2
        assert train_attempts(out, arm)[1]["resumed_from"] >= 1
    assert_same_sweep(out, reference)
    # the finished sweep started once more trains and measures nothing
    scored = {r: (r / "scores.json").stat().st_mtime_ns for r in runs}
    measured = {r: (r / "row.json").stat().st_mtime_ns for r in runs}
    text = run_driver(folder, out, cluster.address, log)
    assert text.count("done earlier, kept") == len(ARMS), text
    assert {r: (r / "scores.json").stat().st_mtime_ns for r in runs} == scored
    assert {r: (r / "row.json").stat().st_mtime_ns for r in runs} == measured
