"""Each ORB-SLAM3 run is its own process: a real run killed by SIGSEGV or SIGKILL, or hung past
its timeout, costs that run only; the condition's other runs are scored and the report names
the failures (issue 42)."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence
from slimseg.slam.condition_runs import EngineRunConfig, evaluate_condition
from slimseg.slam.conditions import Condition
from slimseg.slam.engine_process import FAULT_ENV
from slimseg.slam.orbslam3_config import write_settings
from slimseg.slam.report import RunInfo, write_report
from slimseg.slam.session import ground_truth
from slimseg.slam.vocab import build_vocabulary

pytest.importorskip("pyorbslam3", reason="the [slam] extra")
pytest.importorskip("evo", reason="the [slam] extra")

FRAMES = 15


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> tuple[TumSequence, Path, Path]:
    root = tmp_path_factory.mktemp("iso")
    generate(root / "data", 1, 1, 64, 0, sequences=1, frames=FRAMES + 5, seq_size=(320, 240),
             progress=False, preset="walking_xyz")  # fmt: skip
    seq = TumSequence(root / "data" / "sequences" / "seq_000")
    vocab = build_vocabulary(sorted((seq.root / "rgb").glob("*.png"))[::2], root / "voc.txt",
                             k=6, levels=3, per_image=500)  # fmt: skip
    settings = write_settings(root / "orbslam3_settings.yaml", seq.camera, 320, 240)
    return seq, vocab.path, settings


def test_crashed_killed_and_hung_runs_cost_one_run_each(
    sequence: tuple[TumSequence, Path, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    seq, vocab, settings = sequence
    # runs 2, 3 and 4 fail mid-tracking (the engine reading frame 5), runs 1 and 5 are normal
    monkeypatch.setenv(FAULT_ENV, "2=SIGSEGV@5,3=SIGKILL@5,4=hang@5")
    cfg = EngineRunConfig(runs=5, vocab=vocab, settings=settings, realtime=False, limit=FRAMES,
                          fps=seq.fps, progress=False, timeout_s=10)  # fmt: skip
    gt = ground_truth(seq)
    res = evaluate_condition(seq, Condition("raw", "raw"), gt, cfg, tmp_path / "trajectories")

    outcome = {r.index: r.error or f"ATE {r.score.ate_rmse:.4f} m" for r in res.runs}
    print("\n".join(f"run {k}: {v}" for k, v in outcome.items()))  # shown on failure (or -s)
    assert [r.failed for r in res.runs] == [False, True, True, True, False]
    assert outcome[2] == "engine crashed (SIGSEGV)"
    assert outcome[3] == "engine crashed (SIGKILL)"
    assert outcome[4] == "engine timed out after 10 s (killed)"
    assert [r.index for r in res.scored] == [1, 5]  # the batch went on after every failure
    assert all((tmp_path / "trajectories" / "raw" / f"run{k}.txt").is_file() for k in (1, 5))

    status = res.status()
    print(status)
    assert status.startswith("ok, 3/5 runs failed: run 2 engine crashed (SIGSEGV); run 3 ")
    info = RunInfo(seq.root, FRAMES, "orbslam3", "test", "test", True, 5)
    write_report(tmp_path, info, [res], 0.01)
    assert "3/5 runs failed" in (tmp_path / "results.md").read_text()
    with open(tmp_path / "runs.csv") as f:
        errors = [row["error"] for row in csv.DictReader(f)]
    assert errors == ["", outcome[2], outcome[3], outcome[4], ""]


def test_frames_spill_to_files_when_shared_memory_is_small(
    sequence: tuple[TumSequence, Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A container's /dev/shm (64 MB by default) cannot hold a long sequence: the frames go to
    .npy files beside the run's outputs, mapped by the child, deleted afterwards."""
    from slimseg.slam import engine_process
    from slimseg.slam.conditions import condition_frames

    seq, vocab, settings = sequence
    monkeypatch.setattr(engine_process, "_shm_room", lambda: 0)
    frames = condition_frames(seq, Condition("raw", "raw"), FRAMES)
    with engine_process.SharedFrames(frames, tmp_path) as shared:
        assert {kind for kind, *_ in shared.spec.values()} == {"file"}
        run = engine_process.run_orbslam3_isolated(shared, vocab, settings, False,
                                                   tmp_path / "log", 1.0, 60)  # fmt: skip
    assert isinstance(run, engine_process.EngineRun), run
    assert run.states[0] == "OK" and len(run.trajectory) >= FRAMES - 3
    assert not list(tmp_path.glob(".frames.*"))  # the spill files are gone
