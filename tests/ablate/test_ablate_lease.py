"""What makes a sweep run safe to start again, without a cluster: the lease (a stale holder
gives up, before a file and inside a training run), the stored config read back on another
node, the rows rebuilt from disk in plan order, and the errors given before any run starts
(a sweep folder that cannot be written, Ray missing, flags of the other backend)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

from slimseg.ablate import run_one
from slimseg.ablate.config import config_from_dict, load_ablation_config
from slimseg.ablate.lease import LeaseLost, acquire_lease, read_attempts, state_dir
from slimseg.ablate.rows import ROW_VERSION, join_row, rows_on_disk, timing_keys
from slimseg.ablate.sweep import plan_sweep
from slimseg.cli.main import main
from slimseg.errors import ConfigError, SlimsegError
from slimseg.utils.shipped import shipped_dir

RECIPE = shipped_dir("train") / "cpu-demo.yaml"


def tiny_config(folder: Path, epochs: int = 3) -> Path:
    path = folder / "tiny.yaml"
    path.write_text(
        f"""name: tiny
variants: [yolov8n-seg, {{name: m16, model: yolov8n-seg, spec: {{head: {{num_masks: 16}}}}}}]
data: synth
synth: {{train_images: 16, val_images: 4, imgsz: 64, seed: 0}}
train: {{recipe: {RECIPE}, epochs: {epochs}, imgsz: 64, batch: 8, val_every: {epochs},
         threads: 1}}
seeds: [0, 3]
bench: {{runs: 2, warmup: 1, threads: 1, imgsz: [64, 96], masks: true}}
gflops_imgsz: 64
"""
    )
    return path


def test_newer_attempt_fences_the_stale_one(tmp_path: Path, monkeypatch) -> None:
    state = state_dir(tmp_path, "arm/seed-0")
    monkeypatch.setenv("SLIMSEG_NODE", "host-a/aaaaaa")
    stale = acquire_lease(state, "train", resumed_from=0)
    stale.check("a checkpoint")  # still its own
    monkeypatch.setenv("SLIMSEG_NODE", "host-b/bbbbbb")
    newer = acquire_lease(state, "train", resumed_from=2)
    with pytest.raises(LeaseLost, match=r"host-b/bbbbbb .*stops before row.json"):
        stale.check("row.json")
    newer.check("row.json")
    stale.finish("lease lost")
    newer.finish("done")
    records = read_attempts(state)
    assert [(r["node"], r["outcome"], r["resumed_from"]) for r in records] == [
        ("host-a/aaaaaa", "lease lost", 0),
        ("host-b/bbbbbb", "done", 2),
    ]
    assert not list(state.glob(".*tmp*"))


def test_stored_config_round_trips(tmp_path: Path) -> None:
    cfg = load_ablation_config(tiny_config(tmp_path))
    stored = json.loads(json.dumps(cfg.to_dict()))
    again = config_from_dict(stored, cfg.hash, "sweep.json")
    assert again.hash == cfg.hash and again.variants == cfg.variants
    assert again.train == cfg.train and again.bench == cfg.bench and again.seeds == (0, 3)
    stored["train"]["epochs"] = 99
    with pytest.raises(ConfigError, match=r"sweep\.json: the stored config hashes to"):
        config_from_dict(stored, cfg.hash, "sweep.json")


def test_rows_rebuilt_in_plan_order(tmp_path: Path) -> None:
    cfg = load_ablation_config(tiny_config(tmp_path))
    sizes, masks = cfg.bench_sizes, cfg.bench.masks
    dirs = [tmp_path / name for name in ("a", "b", "c")]
    for d in dirs:
        d.mkdir()
    base = {"variant": "x", "fused_params": 1, "seed": 0}
    base |= {"config_hash": cfg.hash, "row_version": ROW_VERSION}
    timing = dict.fromkeys(timing_keys(sizes, masks), 1.0) | {"train_img_s_from": "steps"}
    # c finished first, b is scored but not measured, a has nothing yet
    (dirs[2] / "row.json").write_text(json.dumps(join_row(base | {"variant": "c"}, timing)))
    (dirs[1] / "scores.json").write_text(json.dumps(base | {"variant": "b"}))
    rows = rows_on_disk(dirs, cfg.hash, sizes, masks)
    assert [r["variant"] for r in rows] == ["b", "c"]
    assert math.isnan(rows[0]["latency_ms"]) and rows[0]["latency_imgsz"] == 64
    keys = list(rows[1])
    assert keys[keys.index("fused_params") + 1] == "latency_ms"
    assert keys[-1] == "train_img_s_from"
    assert rows_on_disk(dirs, "other-hash", sizes, masks) == []


def test_unwritable_sweep_folder_fails_before_any_run(tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the sweep folder should go")
    argv = ["ablate", "--config", str(tiny_config(tmp_path)), "--out", str(blocker / "sweep")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "the sweep folder cannot be written" in err and str(blocker / "sweep") in err
    assert err.count("\n") == 1
    pytest.importorskip("ray")
    # ray: the same error, before Ray is started or reached (this address is never tried)
    assert main([*argv, "--backend", "ray", "--address", "127.0.0.1:9"]) == 2
    assert "the sweep folder cannot be written" in capsys.readouterr().err


def test_ray_missing_gives_the_install_command(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    out = tmp_path / "out"
    argv = ["ablate", "--config", str(tiny_config(tmp_path)), "--out", str(out)]
    assert main([*argv, "--backend", "ray"]) == 2
    err = capsys.readouterr().err
    assert "pip install 'slimseg[ray]'" in err and err.count("\n") == 1
    assert not out.exists()  # nothing written


@pytest.mark.parametrize(
    ("flags", "needle"),
    [
        (["--address", "auto"], "--address: only with --backend ray"),
        (["--backend", "ray", "--gpus-per-run", "1.5"], "--gpus-per-run 1.5: give 0"),
        (["--backend", "ray", "--devices", "2"], "--devices/--num-nodes: with --backend ray"),
        (["--backend", "ray", "--max-retries", "-1"], "--max-retries -1: must be at least 0"),
        (["--resume"], "no sweep to resume"),
    ],
)
def test_bad_flags_name_the_flag(tmp_path: Path, capsys, flags: list[str], needle: str) -> None:
    argv = ["ablate", "--config", str(tiny_config(tmp_path)), "--out", str(tmp_path / "o")]
    assert main([*argv, *flags]) == 2
    assert needle in capsys.readouterr().err


@pytest.mark.slow
def test_stale_holder_stops_inside_training(tmp_path: Path, monkeypatch) -> None:
    """A retry elsewhere takes the lease while this attempt trains epoch 2: it stops before
    writing that epoch's checkpoint, and leaves no scores."""
    cfg = load_ablation_config(tiny_config(tmp_path))
    plan = plan_sweep(cfg, tmp_path / "out", progress=False)
    run = plan.runs[0]

    class Overtaken(run_one.LeaseGuard):
        def on_train_epoch_end(self, trainer, module) -> None:
            if trainer.current_epoch == 1:
                monkeypatch.setenv("SLIMSEG_NODE", "elsewhere/000000")
                acquire_lease(self.lease.state, "train", resumed_from=1)
            super().on_train_epoch_end(trainer, module)

    monkeypatch.setattr(run_one, "LeaseGuard", Overtaken)
    trainer = run_one.TrainerOptions("cpu", "1", 1)
    with pytest.raises(LeaseLost, match="elsewhere/000000"):
        run_one.train_stage(plan, run, trainer, progress=False)
    ckpt = run.dir / "checkpoints" / "last.ckpt"
    assert run_one.checkpoint_epochs(ckpt) == 1  # epoch 2's checkpoint was never written
    assert not (run.dir / "scores.json").exists()
    records = read_attempts(state_dir(plan.out, run.label))
    assert [r.get("outcome") for r in records] == ["lease lost", None]


def test_version_mismatch_is_refused_a_commit_only_noted(monkeypatch, caplog) -> None:
    with pytest.raises(SlimsegError, match="install the same slimseg on every node"):
        run_one.check_version("0.0.0-other", "unknown")
    monkeypatch.setattr(run_one, "git_sha", lambda: "0123456789-dirty")
    with caplog.at_level("WARNING", logger="slimseg.ablate.run_one"):
        run_one.check_version(run_one.__version__, "0123456789")  # an edit since: same commit
        assert not caplog.records
        run_one.check_version(run_one.__version__, "abcdefabcd")  # a commit since
    assert "at git 0123456789-dirty, the driver's was at abcdefabcd" in caplog.text


def test_unreachable_address_fails_fast(tmp_path: Path, capsys) -> None:
    pytest.importorskip("ray")
    argv = ["ablate", "--config", str(tiny_config(tmp_path)), "--out", str(tmp_path / "o")]
    assert main([*argv, "--backend", "ray", "--address", "127.0.0.1:9"]) == 2
    err = capsys.readouterr().err
    assert "--address 127.0.0.1:9: nothing answers there" in err and err.count("\n") == 1
