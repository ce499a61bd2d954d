"""Lightning DDP on CPU (gloo, 2 processes) through ``slimseg train --devices 2``.

Lightning's DDP launcher starts rank 1 by re-running rank 0's command line, so each run is a
small probe script (written into a temp folder) that adds a callback to the CLI's ``train``
and calls ``slimseg.cli.main.main``. The callback writes ``rank{R}.json`` per rank: rank,
strategy, the rank's augmentation of sample 0 in epoch 0, trainable parameters, steps and
per-tensor sums of the model and its EMA (DDP keeps parameters identical on every rank), and
the exception that stopped the rank, if any. It can also poison rank ``nan_rank``'s weights
in epoch 1 or SIGKILL every rank at the start of epoch ``kill_at_epoch``.

Runs: one uninterrupted reference (2 epochs), one with ``--freeze``, one with a NaN on rank 1,
and one killed after epoch 0 then resumed. Waits are bounded by progress
(``tests/progress_wait.py``), not by a fixed timeout.
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
import torch
from progress_wait import wait_process, wait_until

import slimseg
from slimseg.data.synth import generate

pytestmark = pytest.mark.slow

SOURCE_ROOT = str(Path(slimseg.__file__).resolve().parents[1])

PROBE = textwrap.dedent(
    """
    import copy
    import hashlib
    import json
    import os
    import signal
    import sys
    import time
    from pathlib import Path

    import lightning as L
    import torch

    import slimseg.engine.train as engine_train
    from slimseg.cli.main import main
    from slimseg.data.dataset import EpochIndex


    def sums(tensors):
        return {k: float(v.detach().double().sum()) for k, v in tensors if v.is_floating_point()}


    class Probe(L.Callback):
        def __init__(self, opts):
            self.opts, self.report = opts, {}

        def write(self, trainer, **fields):
            self.report.update(fields)
            path = Path(self.opts["report"]) / f"rank{trainer.global_rank}.json"
            path.write_text(json.dumps(self.report))

        def on_train_start(self, trainer, module):
            # this rank's augmentation of sample 0 in epoch 0, on a copy (the loader's untouched)
            dataset = copy.deepcopy(trainer.datamodule.train_set)
            image = dataset[EpochIndex(0, 0, True)].image
            self.write(
                trainer,
                rank=trainer.global_rank,
                pid=os.getpid(),
                world_size=trainer.world_size,
                strategy=type(trainer.strategy).__name__,
                start_epoch=trainer.current_epoch,
                first_sample=hashlib.sha1(image.tobytes()).hexdigest(),
                trainable=sorted(
                    {n.split(".")[0] for n, p in module.model.named_parameters() if p.requires_grad}
                ),
            )

        def on_train_epoch_start(self, trainer, module):
            if trainer.current_epoch == self.opts.get("kill_at_epoch"):
                os.kill(os.getpid(), signal.SIGKILL)

        def on_train_batch_start(self, trainer, module, batch, batch_idx):
            if trainer.current_epoch == 1 and trainer.global_rank == self.opts.get("nan_rank"):
                with torch.no_grad():
                    for p in module.model.parameters():
                        p.fill_(float("nan"))
                self.write(trainer, poisoned_at=time.time())

        def on_exception(self, trainer, module, exception):
            error = f"{type(exception).__name__}: {exception}"
            self.write(trainer, exception=error, stopped_at=time.time())

        def on_train_end(self, trainer, module):
            ema = module.ema.module if module.ema is not None else None
            self.write(
                trainer,
                steps=trainer.global_step,
                run=str(trainer.default_root_dir),
                params=sums(module.model.named_parameters()),
                buffers=sums(module.model.named_buffers()),
                ema_params=sums(ema.named_parameters()) if ema is not None else {},
                ema_buffers=sums(ema.named_buffers()) if ema is not None else {},
            )


    if __name__ == "__main__":
        opts = json.loads(sys.argv[1])
        probe, original = Probe(opts), engine_train.train

        def train_with_probe(*args, **kwargs):
            return original(*args, **kwargs, callbacks=[probe])

        engine_train.train = train_with_probe
        sys.exit(main(sys.argv[2:]))
    """
)

# 8 train images / (2 ranks x batch 2) = 2 steps per epoch and rank
RECIPE = """\
epochs: 2
batch: 2
imgsz: 64
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
        and k != "SLIMSEG_RUN_DIR"
    }
    env.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), OMP_NUM_THREADS="1")
    # the ranks import the slimseg this test imported (a checkout, not another install)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [SOURCE_ROOT, env.get("PYTHONPATH")]))
    return env


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> dict:
    root = tmp_path_factory.mktemp("ddp")
    (root / "recipe.yaml").write_text(RECIPE)
    (root / "probe.py").write_text(PROBE)
    data = generate(root / "data", train=8, val=2, imgsz=64, seed=0, progress=False).data_yaml
    return {"root": root, "data": data}


def launch(setup: dict, name: str, *extra: str, **opts: object) -> dict:
    """``slimseg train`` on 2 CPU ranks through the probe, waited on while it makes progress.
    Returns the exit code, the output and the per-rank reports."""
    work = setup["root"] / name
    report = work / "report"
    report.mkdir(parents=True, exist_ok=True)
    argv = ["train", "--model", "yolov8n-seg", "--data", str(setup["data"])]
    argv += ["--config", str(setup["root"] / "recipe.yaml"), "--accelerator", "cpu"]
    argv += ["--devices", "2", "--out", str(work / "run"), "--quiet", *extra]
    log = work / "output.log"
    with log.open("w") as f:
        proc = subprocess.Popen(
            [
                sys.executable,
                str(setup["root"] / "probe.py"),
                json.dumps(opts | {"report": str(report)}),
                *argv,
            ],
            cwd=work,
            env=_env(),
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    rc = wait_process(proc, [work], f"the {name} run", log)
    paths = [report / f"rank{r}.json" for r in (0, 1)]
    ranks = [json.loads(p.read_text()) if p.is_file() else {} for p in paths]
    for r in ranks:  # rank 1 is rank 0's child: it must be gone too
        pid = r.get("pid")
        wait_until(
            lambda pid=pid: pid is None or not _alive(pid), [work], "rank 1 to exit", log=log
        )
    return {"rc": rc, "output": log.read_text(), "ranks": ranks, "run": work / "run"}


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not yet reaped by its parent) is gone for our purpose
        return Path(f"/proc/{pid}/status").read_text().find("State:\tZ") < 0
    except FileNotFoundError:
        return False


def _differ(a: dict[str, float], b: dict[str, float], rel: float = 1e-6) -> list[str]:
    assert a and a.keys() == b.keys()
    return [k for k in a if abs(a[k] - b[k]) > rel * max(abs(a[k]), abs(b[k]), 1.0)]


@pytest.fixture(scope="module")
def reference(setup: dict) -> dict:
    """One uninterrupted 2-epoch run."""
    done = launch(setup, "reference")
    assert done["rc"] == 0, done["output"][-3000:]
    return done


def test_ddp_trains_on_two_ranks_into_one_run_folder(reference: dict) -> None:
    r0, r1 = reference["ranks"]
    assert (r0["rank"], r1["rank"]) == (0, 1)
    assert r0["world_size"] == r1["world_size"] == 2
    assert r0["strategy"] == r1["strategy"] == "DDPStrategy"
    assert r0["steps"] == r1["steps"] == 4
    run = reference["run"]
    for name in ("weights/last.pt", "weights/best.pt", "checkpoints/last.ckpt"):
        assert (run / name).is_file(), name
    assert len((run / "results.csv").read_text().strip().splitlines()) == 1 + 2
    assert reference["output"].count("run folder:") == 1  # printed by rank 0 only
    assert not run.with_name("run-2").exists()


def test_ddp_parameters_identical_across_ranks(reference: dict) -> None:
    r0, r1 = reference["ranks"]
    for key in ("params", "buffers", "ema_params", "ema_buffers"):
        diff = _differ(r0[key], r1[key])
        assert not diff, f"{key} differ across ranks: {diff[:5]}"


def test_ranks_augment_with_their_own_random_streams(reference: dict) -> None:
    """The same sample in the same epoch: each rank flips, warps and mosaics it its own way
    (both ranks drew rank 0's stream before the rank was part of the seed)."""
    r0, r1 = reference["ranks"]
    assert r0["first_sample"] != r1["first_sample"]


def test_freeze_with_two_devices_trains(setup: dict) -> None:
    """Freezing after the DDP wrap made both ranks fail at the second step ("parameters that
    were not used in producing the loss")."""
    done = launch(setup, "freeze", "--freeze", "backbone,neck,detect", "--epochs", "1")
    assert done["rc"] == 0, done["output"][-3000:]
    for r in done["ranks"]:
        assert r["steps"] == 2 and r["trainable"] == ["mask_coeffs", "proto"], r


def test_nan_on_one_rank_stops_every_rank_and_keeps_the_checkpoint(setup: dict) -> None:
    done = launch(setup, "nan", nan_rank=1)
    assert done["rc"] == 2, done["output"][-3000:]
    # one error from each rank; two processes writing to one pipe can land on one line
    mark = "slimseg train: error:"
    errors = [mark + part for ln in done["output"].splitlines() if ln.startswith(mark)
              for part in ln.split(mark)[1:]]  # fmt: skip
    assert len(errors) == 2, done["output"][-3000:]
    for line in errors:
        assert "loss became" in line and "on rank 1 of 2 at epoch 1" in line, line
        assert "the last good checkpoint is kept" in line
    for r in done["ranks"]:
        assert r["exception"].startswith("NonFiniteLossError"), r["exception"]
    ckpt = torch.load(done["run"] / "checkpoints" / "last.ckpt", weights_only=False)
    assert ckpt["epoch"] == 0  # the end of the last good epoch


def test_resume_after_a_kill_continues_exactly(setup: dict, reference: dict) -> None:
    killed = launch(setup, "killed", kill_at_epoch=1)
    assert killed["rc"] == -9, killed["output"][-3000:]
    assert torch.load(killed["run"] / "checkpoints" / "last.ckpt", weights_only=False)["epoch"] == 0
    resumed = launch(setup, "killed", "--resume")
    assert resumed["rc"] == 0, resumed["output"][-3000:]
    for got, want in zip(resumed["ranks"], reference["ranks"], strict=True):
        assert got["start_epoch"] == 1 and got["steps"] == want["steps"] == 4
        for key in ("params", "buffers", "ema_params"):
            assert got[key] == want[key], f"{key}: {_differ(got[key], want[key], 0.0)[:5]}"
