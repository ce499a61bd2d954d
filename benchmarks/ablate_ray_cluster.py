"""``slimseg ablate --backend ray`` on loopback Ray clusters, one machine, CPU runs.

A 4-run sweep (2 arms x 2 seeds) run four ways: the local backend (the reference), Ray with
1 and with 2 worker nodes (wall time), and Ray with 3 nodes of which one worker node is
killed once a run on it has written its first checkpoint (the timeline of every attempt:
which run ran where, retried when, resumed from which epoch; rows and trained weights
against the reference). Every node takes one run at a time (one CPU each).

    python benchmarks/ablate_ray_cluster.py --work /tmp/ray-bench [--epochs 6] [--images 32]
        [--cases local 1 2 kill]

``kill``, ``1`` and ``2`` compare with the ``local`` case's folder (run it first). Needs the
``[ray]`` extra. Every address is 127.0.0.1 (see tests/ablate/test_ablate_ray.py for why the
environment variables below are set before Ray is imported).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ |= {
    "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
    "RAY_AUTH_MODE": "disabled",
    "OMP_NUM_THREADS": "1",
}

import torch
from ray.cluster_utils import Cluster

from slimseg.ablate.lease import read_attempts, state_dir
from slimseg.ablate.rows import timing_keys
from slimseg.utils.shipped import shipped_dir

ARMS = ("yolov8n-seg", "yolov8n-seg-gs")
SEEDS = (0, 1)
LABELS = [f"{a}/seed-{s}" for s in SEEDS for a in ARMS]
NODE = {"node_ip_address": "127.0.0.1", "object_store_memory": 80 * 1024**2}
HEALTH = {
    "health_check_period_ms": 500,
    "health_check_failure_threshold": 3,
    "health_check_timeout_ms": 500,
}


def write_config(work: Path, epochs: int, images: int) -> Path:
    path = work / "sweep4.yaml"
    recipe = shipped_dir("train") / "cpu-demo.yaml"
    path.write_text(
        f"name: sweep4\nvariants: [{', '.join(ARMS)}]\ndata: synth\n"
        f"synth: {{train_images: {images}, val_images: 8, imgsz: 64, seed: 0}}\n"
        f"train: {{recipe: {recipe}, epochs: {epochs}, imgsz: 64, batch: 8, "
        f"val_every: {epochs}, threads: 1}}\n"
        f"seeds: [{', '.join(map(str, SEEDS))}]\n"
        "bench: {runs: 5, warmup: 2, threads: 1}\ngflops_imgsz: 64\n"
    )
    return path


def argv(config: Path, out: Path, address: str | None) -> list[str]:
    cmd = [sys.executable, "-m", "slimseg", "ablate", "--config", str(config), "--out", str(out)]
    cmd.append("--quiet")
    if address is not None:
        cmd += ["--backend", "ray", "--address", address, "--throughput-steps", "10"]
    return cmd


def start_cluster(workers: int, head_cpus: int) -> tuple[Cluster, list]:
    head = {"num_cpus": head_cpus, "include_dashboard": False, **NODE, "_system_config": HEALTH}
    cluster = Cluster(initialize_head=True, head_node_args=head)
    nodes = [cluster.add_node(num_cpus=1, **NODE) for _ in range(workers)]
    cluster.wait_for_nodes()
    return cluster, nodes


def deterministic(out: Path) -> list[dict]:
    skip = {*timing_keys((64,), False), "train_img_s_from", "git_sha"}  # commits may land
    rows = [json.loads((out / "variants" / lab / "row.json").read_text()) for lab in LABELS]
    return [{k: v for k, v in row.items() if k not in skip} for row in rows]


def same_weights(a: Path, b: Path) -> bool:
    for lab in LABELS:
        x, y = (
            torch.load(o / "variants" / lab / "weights" / "best.pt", weights_only=False)
            for o in (a, b)
        )
        sx, sy = x["state_dict"], y["state_dict"]
        if sx.keys() != sy.keys() or not all(torch.equal(sx[k], sy[k]) for k in sx):
            return False
    return True


def timeline(out: Path, t0: float) -> None:
    """Every attempt, seconds after the driver started: its task, its lease (the run's
    process up and running), its end."""
    print(
        f"{'run':22} {'stage':7} {'#':>2} {'node':11} {'task':>6} {'lease':>6} {'end':>7} "
        f"{'resumed':>7}  outcome"
    )
    for stage in ("train", "measure"):
        for lab in LABELS:
            recs = [r for r in read_attempts(state_dir(out, lab)) if r["stage"] == stage]
            for k, r in enumerate(recs, 1):
                task = r.get("task_started", float("nan")) - t0
                end = f"{r['finished'] - t0:7.1f}" if "finished" in r else "   --"
                print(
                    f"{lab:22} {stage:7} {k:2} {r['node']:11} {task:6.1f} "
                    f"{r['started'] - t0:6.1f} {end:>7} {r.get('resumed_from', ''):>7}  "
                    f"{r.get('outcome', 'cut off (node killed)')}"
                )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--epochs", type=int, default=6)
    p.add_argument("--images", type=int, default=32)
    p.add_argument("--cases", nargs="+", default=["local", "1", "2", "kill"])
    args = p.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    config = write_config(args.work, args.epochs, args.images)
    ref = args.work / "local"
    for case in args.cases:
        out, log = args.work / f"case-{case}", args.work / f"case-{case}.log"
        cluster, workers = (
            (None, [])
            if case == "local"
            else start_cluster(2 if case == "kill" else int(case), 1 if case == "kill" else 0)
        )
        address = None if cluster is None else cluster.address
        t0 = time.time()
        with log.open("w") as f:
            proc = subprocess.Popen(
                argv(config, ref if case == "local" else out, address),
                stdout=f,
                stderr=subprocess.STDOUT,
            )
        if case == "kill":
            kill_a_worker(cluster, workers, out, proc, t0)
        rc = proc.wait()
        wall = time.time() - t0
        if cluster is not None:
            cluster.shutdown()
        print(f"\n== {case}: exit {rc}, wall {wall:.1f} s", flush=True)
        if case != "local":
            print(
                f"rows equal the local backend's (timing columns aside): "
                f"{deterministic(out) == deterministic(ref)}; best.pt bit-equal: "
                f"{same_weights(out, ref)}"
            )
            timeline(out, t0)
        if case == "kill":
            print("driver's progress lines:")
            print("\n".join(x for x in log.read_text().splitlines() if x.startswith("[")))


def kill_a_worker(cluster: Cluster, workers: list, out: Path, proc, t0: float) -> None:
    """Remove (SIGKILL) the worker node of the first run past its first epoch."""
    head = cluster.head_node.node_id[:6]
    while True:
        assert proc.poll() is None, "the sweep ended before a run wrote a checkpoint"
        for lab in LABELS:
            recs = [r for r in read_attempts(state_dir(out, lab)) if r["stage"] == "train"]
            ckpt = out / "variants" / lab / "checkpoints" / "last.ckpt"
            if recs and ckpt.is_file() and not recs[-1]["node"].endswith(head):
                node = recs[-1]["node"].split("/")[1]
                victim = next(w for w in workers if w.node_id.startswith(node))
                cluster.remove_node(victim, allow_graceful=False)
                print(f"killed worker node {node} at {time.time() - t0:.1f} s, running {lab}")
                return
        time.sleep(0.05)


if __name__ == "__main__":
    main()
