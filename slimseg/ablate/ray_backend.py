"""``slimseg ablate --backend ray``: the sweep's runs as Ray tasks across a cluster.

Two phases, both driven by :mod:`slimseg.ablate.driver`:

1. *train*: one Ray task per unfinished run (``num_cpus``/``num_gpus`` per run, fractional
   GPUs allowed), all submitted at once. A task starts the run as its own process
   (``python -m slimseg.ablate.run_one``, killed with its worker) and returns when the
   run's ``scores.json`` is written. Ray retries a task whose worker or node died (up to
   ``max_retries``); the retry resumes from the run's checkpoint, and the lease of
   :mod:`slimseg.ablate.lease` fences off the attempt it replaced. An error in the run
   itself (bad config, a loss gone NaN) is not retried: the run is reported failed, the
   others go on, and a rerun of the command tries it again.
2. *measure*: once no run trains any more, one task measures every scored run in plan
   order on one node (latency, a timed training burst: :mod:`slimseg.ablate.train_bench`),
   so no timing column is taken while runs share a machine.

After each finished run the reports are rebuilt from the rows on disk in plan order, so a
sweep cut anywhere and resumed writes the reports of one that never stopped. Ray is
imported by this module only; nothing else of slimseg needs it.

This module is the Ray side (the tasks, the session, the cluster checks); the sweep that
uses them, and its entry :func:`~slimseg.ablate.driver.run_sweep_ray`, are
:mod:`slimseg.ablate.driver`, which imports this module and never the other way round.
"""

from __future__ import annotations

import ctypes
import math
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from slimseg.ablate.lease import TASK_STARTED_ENV, state_dir
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_text
from slimseg.utils.extras import install_command

INSTALL_HINT = install_command("ray")


class RunFailed(Exception):
    """A run's own process failed (not retried by Ray: the message says why)."""


def import_ray() -> Any:
    """The ``ray`` module, or a one-line SlimsegError with the install command."""
    try:
        import ray
    except ImportError:
        raise SlimsegError(f"--backend ray needs Ray, an optional extra: {INSTALL_HINT}") from None
    return ray


@dataclass(frozen=True)
class RayOptions:
    """How the sweep uses the cluster. ``address``: ``local`` (start Ray on this machine
    for the sweep, stop it after), ``auto`` (the running cluster) or ``HOST:PORT``.
    ``gpus_per_run`` None: 1 when the cluster has GPUs, else 0; below 1 packs several runs
    onto a GPU, 2 or more trains the run with Lightning DDP on that many GPUs of one node."""

    address: str = "local"
    gpus_per_run: float | None = None
    cpus_per_run: float = 1.0
    max_retries: int = 3
    throughput_steps: int = 20
    poll_s: float = 2.0
    init_kwargs: dict = field(default_factory=dict)  # extra ray.init arguments (tests)


@contextmanager
def ray_session(ray: Any, opts: RayOptions) -> Iterator[None]:
    """Connected to the cluster for the block; a Ray started here (``local``) is stopped
    after it, and a caller's own connection is left as it was."""
    if ray.is_initialized():
        yield
        return
    kwargs = {"include_dashboard": False, "log_to_driver": False} | opts.init_kwargs
    if opts.address != "local":
        kwargs["address"] = opts.address
        _check_reachable(opts.address)
    try:
        ray.init(**kwargs)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = "a local Ray instance" if opts.address == "local" else opts.address
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SlimsegError(
            f"--address {opts.address}: could not start or reach {where} ({first}); start "
            "the cluster with 'ray start --head' or pass --address HOST:PORT of its head"
        ) from None
    try:
        yield
    finally:
        ray.shutdown()


def _check_reachable(address: str) -> None:
    """A HOST:PORT that nothing answers on fails here in seconds (``ray.init`` would retry
    for minutes)."""
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or "://" in address:
        return  # auto, or a form Ray resolves itself
    try:
        socket.create_connection((host, int(port)), timeout=10).close()
    except OSError as exc:
        raise SlimsegError(
            f"--address {address}: nothing answers there ({exc.strerror or exc}); start the "
            "head with 'ray start --head' and pass the address it prints, or --address auto "
            "on a node of the cluster"
        ) from None


def node_label(ray: Any) -> str:
    """``HOST/NODE``: the host name and the first 6 hex digits of the Ray node id (nodes of
    a test cluster share a host)."""
    node = ray.get_runtime_context().get_node_id()
    return f"{socket.gethostname()}/{node[:6]}"


def _die_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn`` that makes the run's process get SIGKILL when the Ray worker that
    started it dies (Linux; None elsewhere). libc is loaded here, in the parent: the
    function the child runs between fork and exec only makes the one system call."""
    if not sys.platform.startswith("linux"):
        return None
    prctl = ctypes.CDLL("libc.so.6", use_errno=True).prctl

    def preexec() -> None:  # pragma: no cover - runs in the child before exec
        prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG

    return preexec


def train_task(out: str, label: str, expect: list[str], accelerator: str, devices: str) -> str:
    """Ray task: train and score one run in its own process; returns the node it ran on."""
    import ray

    node = node_label(ray)
    state = state_dir(Path(out), label)
    state.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
    log = state / f"train-{stamp}-{os.getpid()}.log"
    cmd = [sys.executable, "-m", "slimseg.ablate.run_one", out, label, "--stage", "train"]
    cmd += ["--expect", *expect, "--accelerator", accelerator, "--devices", devices, "--quiet"]
    env = os.environ | {"SLIMSEG_NODE": node, "PYTHONUNBUFFERED": "1"}
    env[TASK_STARTED_ENV] = repr(time.time())  # the attempt record keeps the start-up cost
    with log.open("w") as f:
        proc = subprocess.run(  # the exit code is read below
            cmd, stdout=f, stderr=subprocess.STDOUT, env=env, preexec_fn=_die_with_parent()
        )
    if proc.returncode != 0:
        lines = [x for x in log.read_text(errors="replace").splitlines() if x.strip()]
        last = lines[-1] if lines else "no output"
        raise RunFailed(f"on {node}: exit {proc.returncode}: {last} (log: {log})")
    return node


def measure_task(
    out: str, labels: list[str], expect: list[str], accelerator: str, steps: int
) -> str:
    """Ray task: measure the scored runs ``labels`` one after another on this node."""
    import ray

    from slimseg.ablate.run_one import check_version, load_plan, measure_stage

    node = node_label(ray)
    before = os.environ.get("SLIMSEG_NODE")
    os.environ["SLIMSEG_NODE"] = node  # names the lease holder; put back below
    try:
        check_version(expect[1], expect[2])
        plan = load_plan(Path(out), expect[0])
        for label in labels:
            measure_stage(plan, plan.run(label), accelerator, steps)
    finally:
        if before is None:
            os.environ.pop("SLIMSEG_NODE", None)
        else:
            os.environ["SLIMSEG_NODE"] = before
    return node


def probe_task(out: str, token: str) -> str:
    """Ray task: '' when this node reads the driver's probe file in ``out`` and writes its
    own there, else what went wrong."""
    import ray

    node = node_label(ray)
    probe = Path(out) / f".shared-probe-{token}"
    try:
        if probe.read_text() != token:
            return f"{node} reads another {probe.name}"
        write_text(Path(out) / f".shared-probe-{token}-{node.replace('/', '-')}", node)
    except FileNotFoundError:
        return f"{node} does not see {probe} (the folder is not shared with it)"
    except OSError as exc:
        return f"{node} cannot write in {out} ({exc.strerror or exc})"
    return ""


def check_shared(ray: Any, out: Path, cpus: float, gpus: float) -> int:
    """SlimsegError unless every node that could take a run sees ``out`` and can write in
    it; returns how many such nodes there are."""
    fits = [
        n
        for n in ray.nodes()
        if n.get("Alive")
        and n["Resources"].get("CPU", 0) >= cpus
        and n["Resources"].get("GPU", 0) >= gpus
    ]
    if not fits:
        raise SlimsegError(
            f"no node of the cluster has {cpus:g} CPUs and {gpus:g} GPUs for a run; lower "
            "--cpus-per-run/--gpus-per-run or add nodes"
        )
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    token = secrets.token_hex(6)
    probe = write_text(out / f".shared-probe-{token}", token)
    task = ray.remote(probe_task)
    refs = [
        task.options(
            num_cpus=0,
            scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False),
        ).remote(str(out), token)
        for n in fits
    ]
    try:
        problems = [p for p in ray.get(refs, timeout=300) if p]
    finally:
        probe.unlink(missing_ok=True)
        for path in out.glob(f".shared-probe-{token}-*"):
            path.unlink(missing_ok=True)
    if problems:
        raise SlimsegError(
            f"{out}: the sweep folder must be on storage every node mounts at the same path "
            f"(NFS, a cluster filesystem): {'; '.join(problems)}"
        )
    return len(fits)


def launch_options(gpus: float) -> tuple[str, str]:
    """Lightning accelerator and devices of a run given ``gpus`` per run."""
    if gpus <= 0:
        return "cpu", "1"
    return "gpu", str(max(1, math.floor(gpus)))
