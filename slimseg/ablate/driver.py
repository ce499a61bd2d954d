"""``slimseg ablate --backend ray``: :func:`run_sweep_ray`, and the driver of the sweep, which
submits the runs as the Ray tasks of :mod:`slimseg.ablate.ray_backend`, follows their attempts
on disk, logs progress and rebuilds the reports after each finished run."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from slimseg.ablate.config import AblationConfig
from slimseg.ablate.lease import read_attempts, state_dir
from slimseg.ablate.ray_backend import (
    RayOptions,
    check_shared,
    import_ray,
    launch_options,
    measure_task,
    ray_session,
    train_task,
)
from slimseg.ablate.rows import read_row, read_scores
from slimseg.ablate.sweep import Run, SweepPlan, git_sha, plan_sweep
from slimseg.version import __version__

logger = logging.getLogger(__name__)


class RayDriver:
    """One ray sweep from this process (see :func:`run_sweep_ray`)."""

    def __init__(
        self,
        ray: Any,
        cfg: AblationConfig,
        out: Path,
        opts: RayOptions,
        progress: bool,
        log: Callable[[str], None],
    ) -> None:
        self.ray, self.cfg, self.out, self.opts = ray, cfg, Path(out).resolve(), opts
        self.progress, self._log = progress, log
        self.t0 = time.monotonic()
        self.seen: dict[str, set[str]] = {}  # attempt tokens already reported, per run
        self.failed: list[str] = []
        self.plan: SweepPlan | None = None

    def log(self, text: str) -> None:
        self._log(f"[{time.monotonic() - self.t0:7.1f}s] {text}")

    def tag(self, run: Run) -> str:
        assert self.plan is not None
        return f"[{self.plan.runs.index(run) + 1}/{len(self.plan.runs)}] {run.label}"

    def run(self) -> tuple[list[dict], list[str]]:
        """Both phases; returns the rows in plan order and one line per failed run."""
        plan = self.plan = plan_sweep(self.cfg, self.out, self.progress)
        expect = [self.cfg.hash, __version__, git_sha()]
        with ray_session(self.ray, self.opts):
            gpus = self.opts.gpus_per_run
            if gpus is None:
                gpus = 1.0 if self.ray.cluster_resources().get("GPU", 0) > 0 else 0.0
            cpus = self.opts.cpus_per_run
            nodes = check_shared(self.ray, plan.out, cpus, gpus)
            self.log(
                f"ray: {nodes} node(s) can take a run ({cpus:g} CPU, {gpus:g} GPU each); "
                f"{plan.out} is shared by them"
            )
            self.train_phase(expect, cpus, gpus)
            self.measure_phase(expect, cpus, gpus)
        plan.write_reports()
        return plan.rows(), self.failed

    # ------------------------------------------------------------------ phase 1
    def train_phase(self, expect: list[str], cpus: float, gpus: float) -> None:
        assert self.plan is not None
        plan, ray = self.plan, self.ray
        todo = []
        for run in plan.runs:
            if read_row(run.dir, plan.cfg.hash) or read_scores(run.dir, plan.cfg.hash):
                self.log(f"{self.tag(run)}: done earlier, kept")
            else:
                todo.append(run)
        if not todo:
            return
        accelerator, devices = launch_options(gpus)
        task = ray.remote(train_task).options(
            num_cpus=cpus, num_gpus=gpus, max_retries=self.opts.max_retries, retry_exceptions=False
        )
        refs = {task.remote(str(plan.out), r.label, expect, accelerator, devices): r for r in todo}
        self.log(f"train: {len(refs)} run(s) submitted ({accelerator}, devices {devices})")
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1, timeout=self.opts.poll_s)
            self.report_attempts(list(refs.values()))
            for ref in ready:
                run = refs.pop(ref)
                try:
                    node = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    self.fail(run, exc)
                else:
                    self.report_attempts([run])
                    scores = read_scores(run.dir, plan.cfg.hash) or {}
                    n = len(self.attempts(run))
                    self.log(
                        f"{self.tag(run)}: trained on {node} (attempt {n}): "
                        f"box mAP50-95 {scores.get('box_map50_95', math.nan):.3f}, "
                        f"seg {scores.get('seg_map50_95', math.nan):.3f}"
                    )
                plan.write_reports()
                self.status(list(refs.values()))

    def attempts(self, run: Run) -> list[dict]:
        """The run's train attempts recorded on disk, oldest first."""
        records = read_attempts(state_dir(self.out, run.label))
        return [r for r in records if r.get("stage") == "train"]

    def report_attempts(self, runs: list[Run]) -> None:
        """A line for every attempt started since the last poll (a retry says so)."""
        for run in runs:
            records = self.attempts(run)
            seen = self.seen.setdefault(run.label, set())
            for k, rec in enumerate(records, 1):
                if rec["token"] in seen:
                    continue
                seen.add(rec["token"])
                epochs = rec.get("resumed_from", 0)
                start = f"resuming after epoch {epochs}" if epochs else "from scratch"
                what = "retried" if k > 1 else "running"
                self.log(f"{self.tag(run)}: {what} on {rec['node']} (attempt {k}), {start}")

    def status(self, pending: list[Run]) -> None:
        """Counts over the sweep: done (scored), running (pending, an attempt started: a
        run whose node died counts here until its retry starts), queued (pending, no attempt
        yet), retried (more than one attempt), failed."""
        assert self.plan is not None
        h = self.plan.cfg.hash
        done = sum(bool(read_scores(r.dir, h) or read_row(r.dir, h)) for r in self.plan.runs)
        running = sum(bool(self.attempts(r)) for r in pending)
        retried = sum(len(self.attempts(r)) > 1 for r in self.plan.runs)
        self.log(
            f"progress: {done} done, {running} running, {len(pending) - running} queued, "
            f"{retried} retried, {len(self.failed)} failed of {len(self.plan.runs)}"
        )

    def fail(self, run: Run, exc: Exception) -> None:
        cause = getattr(exc, "cause", None) or exc
        lines = [x for x in str(cause).strip().splitlines() if x.strip()]
        text = lines[-1] if lines else type(cause).__name__
        self.failed.append(f"{run.label}: {text}")
        self.log(f"{self.tag(run)}: FAILED: {text}")

    # ------------------------------------------------------------------ phase 2
    def measure_phase(self, expect: list[str], cpus: float, gpus: float) -> None:
        """Every scored run without a row measured by one task, in plan order, on one node,
        after all training is over."""
        assert self.plan is not None
        plan, ray, h = self.plan, self.ray, self.plan.cfg.hash
        todo = [r for r in plan.runs if read_row(r.dir, h) is None and read_scores(r.dir, h)]
        if not todo:
            return
        accelerator = "gpu" if gpus > 0 else "cpu"
        task = ray.remote(measure_task).options(
            num_cpus=cpus,
            num_gpus=1 if gpus > 0 else 0,
            max_retries=self.opts.max_retries,
            retry_exceptions=False,
        )
        labels = [r.label for r in todo]
        ref = task.remote(str(plan.out), labels, expect, accelerator, self.opts.throughput_steps)
        self.log(f"measure: {len(todo)} run(s), one at a time on one node (nothing else runs)")
        left = list(todo)
        while left:
            ready, _ = ray.wait([ref], timeout=self.opts.poll_s)
            for run in list(left):
                if (row := read_row(run.dir, h)) is not None:
                    left.remove(run)
                    plan.write_reports()
                    self.log(
                        f"{self.tag(run)}: measured: {row['latency_ms']:.1f} ms, "
                        f"{row['train_img_s']:.1f} train img/s"
                    )
            if ready:
                try:
                    node = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    for run in left:
                        self.fail(run, exc)
                    return
                if left:  # finished without these rows: cannot happen, say so if it does
                    for run in left:
                        self.fail(run, RuntimeError(f"not measured on {node}"))
                    return
                self.log(f"measure: done on {node}")


def run_sweep_ray(
    cfg: AblationConfig,
    out: Path,
    opts: RayOptions,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> tuple[list[dict], list[str]]:
    """Run the sweep ``cfg`` on a Ray cluster; returns the rows in plan order and the
    failures (one line per failed run, empty when every run finished). Progress lines go
    to ``log`` (default: this module's logger at INFO)."""
    ray = import_ray()  # the install hint comes before anything is written
    return RayDriver(ray, cfg, out, opts, progress, log or logger.info).run()
