"""Training runs end to end: run folder, weights, val JSON, resume, NaN stop."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.engine import module as module_mod
from slimseg.engine.config import TrainConfig
from slimseg.engine.module import NonFiniteLossError
from slimseg.engine.train import train
from slimseg.models.checkpoint import load_weights

TINY = TrainConfig(
    epochs=1,
    batch=4,
    imgsz=96,
    optimizer="adamw",
    lr0=0.002,
    warmup_epochs=0.0,
    close_mosaic=0,
    workers=0,
    ema_decay=0.9,
)


@pytest.fixture(scope="module")
def data_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "ds"
    return generate(out, 8, 4, 96, seed=2, progress=False).data_yaml


@pytest.fixture(scope="module")
def run_dir(data_yaml: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "run"
    _, out = train("yolov8n-seg", data_yaml, TINY, out, accelerator="cpu", progress=False)
    return out


def test_run_folder_layout(run_dir: Path) -> None:
    for rel in ("weights/best.pt", "weights/last.pt", "checkpoints/last.ckpt", "args.yaml"):
        assert (run_dir / rel).is_file(), rel
    rows = (run_dir / "results.csv").read_text().splitlines()
    assert rows[0].startswith("epoch,") and "val/mask_map50_95" in rows[0] and len(rows) == 2
    assert any((run_dir / "tb").iterdir())


def test_weights_load_without_lightning_and_fuse(run_dir: Path) -> None:
    model, info = load_weights(run_dir / "weights" / "last.pt")
    assert info.spec.name == "yolov8n-seg" and len(info.names) == model.num_classes == 6
    assert info.mobility[0] == 1.0 and "box" in info.metrics
    fused, _ = load_weights(run_dir / "weights" / "last.pt", fused=True)
    x = torch.rand(1, 3, 96, 96)
    with torch.no_grad():
        a, b = model(x)[0], fused(x)[0]
    assert (a[:, :4] - b[:, :4]).abs().max() < 1e-3
    ckpt_model, _ = load_weights(run_dir / "checkpoints" / "last.ckpt")
    for k, v in model.state_dict().items():
        torch.testing.assert_close(ckpt_model.state_dict()[k], v)


def test_val_json_layout(run_dir: Path, data_yaml: Path, capsys: pytest.CaptureFixture) -> None:
    argv = ["val", "--weights", str(run_dir / "weights" / "best.pt"), "--data", str(data_yaml)]
    assert main([*argv, "--json", "--workers", "0"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result) == {"box", "mask", "per_class", "speed_ms"}
    assert set(result["box"]) == {"map50_95", "map50"} and set(result["mask"]) == {
        "map50_95",
        "map50",
    }
    assert len(result["per_class"]) == 6
    assert result["speed_ms"]["inference"] > 0


def test_resume_continues_the_run(run_dir: Path, data_yaml: Path) -> None:
    module, out = train(
        "yolov8n-seg",
        data_yaml,
        TINY.override(epochs=2),
        run_dir,
        resume=True,
        accelerator="cpu",
        progress=False,
    )
    assert out == run_dir and module.current_epoch == 2
    assert len((run_dir / "results.csv").read_text().splitlines()) == 3


def test_nan_loss_stops_and_keeps_last_checkpoint(
    data_yaml: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, out = train("yolov8n", data_yaml, TINY, tmp_path / "r", accelerator="cpu", progress=False)
    ckpt = out / "checkpoints" / "last.ckpt"
    before = ckpt.read_bytes()

    def poisoned(model: torch.nn.Module):
        def criterion(outputs: object, batch: dict):
            nan = sum(f.sum() for f in outputs.feats) * float("nan")
            return nan, {"box": nan.detach()}

        return criterion

    monkeypatch.setattr(module_mod, "build_criterion", poisoned)
    with pytest.raises(NonFiniteLossError, match="loss became nan"):
        train(
            "yolov8n",
            data_yaml,
            TINY.override(epochs=2),
            out,
            resume=True,
            accelerator="cpu",
            progress=False,
        )
    assert ckpt.read_bytes() == before


def test_resume_without_checkpoint_is_a_clear_error(data_yaml: Path, tmp_path: Path) -> None:
    argv = ["train", "--model", "yolov8n", "--data", str(data_yaml), "--out", str(tmp_path)]
    assert main([*argv, "--resume", "--quiet"]) == 2


class _Killed(RuntimeError):
    pass


def test_killed_and_resumed_run_ends_where_an_uninterrupted_run_does(
    data_yaml: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # two persistent loader workers, mosaic closed for the second epoch: the epoch's seed and
    # the mosaic switch must reach the workers of both runs alike
    cfg = TINY.override(epochs=2, workers=2, close_mosaic=1)
    _, straight = train(
        "yolov8n-seg", data_yaml, cfg, tmp_path / "a", accelerator="cpu", progress=False
    )

    original = module_mod.ZooModule.on_train_batch_start

    def kill_in_second_epoch(self, batch: dict, batch_idx: int) -> None:
        if self.current_epoch == 1:
            raise _Killed("simulated kill")
        original(self, batch, batch_idx)

    monkeypatch.setattr(module_mod.ZooModule, "on_train_batch_start", kill_in_second_epoch)
    with pytest.raises(_Killed):
        train("yolov8n-seg", data_yaml, cfg, tmp_path / "b", accelerator="cpu", progress=False)
    monkeypatch.undo()
    _, resumed = train(
        "yolov8n-seg",
        data_yaml,
        cfg,
        tmp_path / "b",
        resume=True,
        accelerator="cpu",
        progress=False,
    )
    a, _ = load_weights(straight / "weights" / "last.pt")
    b, _ = load_weights(resumed / "weights" / "last.pt")
    for key, value in a.state_dict().items():
        torch.testing.assert_close(b.state_dict()[key], value, atol=1e-5, rtol=1e-4)


def test_init_from_our_weights_reports_what_loaded(run_dir: Path) -> None:
    from slimseg.engine.train import transfer_weights
    from slimseg.models.registry import get_spec

    spec = get_spec("yolov8n-seg-rep", 6).to_dict()
    target = module_mod.ZooModule(spec, TINY.__dict__, ["c"] * 6)
    report = transfer_weights(target, run_dir / "weights" / "best.pt")
    assert report.startswith("loaded ") and "kept the initial values" in report  # head differs
    source, _ = load_weights(run_dir / "weights" / "best.pt")
    key = "backbone.stem.0.conv.weight"
    torch.testing.assert_close(target.model.state_dict()[key], source.state_dict()[key])
    torch.testing.assert_close(target.ema.module.state_dict()[key], source.state_dict()[key])


def test_cli_train_logs_the_weights_report_and_restores_threads(
    run_dir: Path, data_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    before = torch.get_num_threads()
    wanted = 1 if before != 1 else 2
    argv = ["train", "--model", "yolov8n-seg", "--data", str(data_yaml), "--imgsz", "96"]
    argv += ["--epochs", "1", "--batch", "4", "--workers", "0", "--threads", str(wanted)]
    argv += ["--weights", str(run_dir / "weights" / "best.pt"), "--out", str(tmp_path / "r")]
    assert main([*argv, "--accelerator", "cpu", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "loaded " in out and "tensors from" in out  # the library's logger reaches the user
    assert torch.get_num_threads() == before


def test_float16_precision_on_cpu_is_refused_before_any_write(
    data_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    argv = ["train", "--model", "yolov8n-seg", "--data", str(data_yaml), "--precision"]
    argv += ["16-mixed", "--accelerator", "cpu", "--out", str(tmp_path / "r")]
    assert main(argv) == 2
    assert "16-mixed needs a CUDA device" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="the error is for machines without CUDA")
@pytest.mark.parametrize(("device", "needle"), [("cuda", "no CUDA device"), ("tpu7", "expected")])
def test_val_device_errors_are_one_line(
    run_dir: Path, data_yaml: Path, device: str, needle: str, capsys: pytest.CaptureFixture
) -> None:
    argv = ["val", "--weights", str(run_dir / "weights" / "best.pt"), "--data", str(data_yaml)]
    assert main([*argv, "--device", device]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1


def test_freeze_trains_only_the_mask_branch_of_a_trained_trunk(
    run_dir: Path, data_yaml: Path, tmp_path: Path
) -> None:
    """--freeze backbone,neck,detect: those parts (BatchNorm statistics included) leave the
    run exactly as they came from --weights; the mask branch moves; the -hr twin takes the
    trunk (shapes matched) and trains its new prototype path."""
    start, _ = load_weights(run_dir / "weights" / "last.pt")
    frozen = ("backbone", "neck", "detect")
    for name in ("yolov8n-seg", "yolov8n-seg-hr"):
        _, out = train(
            name,
            data_yaml,
            TINY,
            tmp_path / name,
            accelerator="cpu",
            progress=False,
            weights=str(run_dir / "weights" / "last.pt"),
            freeze=frozen,
        )
        tuned, _ = load_weights(out / "weights" / "last.pt")
        before, after = start.state_dict(), tuned.state_dict()
        for key, value in after.items():
            if key.split(".")[0] in frozen:
                assert torch.equal(value, before[key]), key
        moved = [
            k
            for k, v in after.items()
            if k.startswith("proto.")
            and k in before
            and v.shape == before[k].shape
            and not torch.equal(v, before[k])
        ]
        assert moved, f"{name}: the prototype path did not train"


def test_freeze_with_an_unknown_part_fails_before_any_write(
    data_yaml: Path, tmp_path: Path
) -> None:
    argv = ["train", "--model", "yolov8n-seg", "--data", str(data_yaml), "--epochs", "1"]
    assert (
        main([*argv, "--imgsz", "64", "--freeze", "backbone,head", "--out", str(tmp_path / "r")])
        == 2
    )
    assert not (tmp_path / "r").exists()


def test_best_weights_are_written_before_last(tmp_path: Path, monkeypatch) -> None:
    """``weights/last.pt`` at the last epoch tells a resumed sweep the run is trained: a run
    killed between the two writes must not have a last.pt without its best.pt (a Ray worker
    killed there left an arm that no retry could finish)."""
    from types import SimpleNamespace

    from slimseg.engine import train as train_mod

    written: list[str] = []

    def save(path: Path, model: object, info: object) -> None:
        written.append(path.name)
        if len(written) == 1:
            raise KeyboardInterrupt  # the node dies after the first write

    monkeypatch.setattr(train_mod, "save_weights", save)
    writer = train_mod.RunWriter(tmp_path)
    metrics = {"val/mask_map50_95": torch.tensor(0.0)}
    trainer = SimpleNamespace(
        is_global_zero=True, sanity_checking=False, current_epoch=2, callback_metrics=metrics
    )
    module = SimpleNamespace(
        cfg=TrainConfig(epochs=3), spec=None, names=["person"], mobility=[1.0],
        last_metrics={}, eval_model=None,
    )  # fmt: skip
    with pytest.raises(KeyboardInterrupt):
        writer.on_validation_end(trainer, module)
    assert written == ["best.pt"]
