"""``slimseg ablate`` arms, seeds, row metrics and latency by size: spec overrides merged and
checked strictly, the config hash, mean ± spread over seeds, the latency columns, and a
2 arms × 2 seeds sweep that is interrupted after its first run and resumed."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from slimseg.ablate.arms import deep_merge
from slimseg.ablate.config import load_ablation_config
from slimseg.ablate.latency import BenchOptions, bench_latency, latency_columns
from slimseg.ablate.metrics import ROW_METRICS, run_weights, score_run
from slimseg.ablate.report import markdown
from slimseg.ablate.summary import mean_spread, summarize
from slimseg.ablate.sweep import run_sweep, sweep_runs
from slimseg.data.coco import CocoDataset
from slimseg.data.config import DataConfig
from slimseg.deploy.predictor import Predictor
from slimseg.errors import SlimsegError
from slimseg.models.checkpoint import WeightsInfo
from slimseg.models.registry import build_model, get_spec
from slimseg.models.specs import ModelSpec, load_spec
from slimseg.utils.shipped import shipped_dir

RECIPE = shipped_dir("train") / "cpu-demo.yaml"
M16 = "{name: n-m16, model: yolov8n-seg, spec: {head: {num_masks: 16}}}"


def write_config(tmp_path: Path, variants: str = f"[yolov8n-seg, {M16}]", **extra: str) -> Path:
    """A tiny sweep (64 px, 1 epoch, 8 train / 4 val images); ``extra``: top-level fields."""
    fields = {
        "name": "arms",
        "variants": variants,
        "data": "synth",
        "synth": "{train_images: 8, val_images: 4, imgsz: 64, seed: 0}",
        "train": f"{{recipe: {RECIPE}, epochs: 1, imgsz: 64, batch: 8, val_every: 1, "
        "threads: 1, workers: 0}",
        "bench": "{runs: 2, warmup: 1, threads: 1}",
        "gflops_imgsz": "64",
    } | extra
    path = tmp_path / "arms.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in fields.items()))
    return path


def test_deep_merge_recurses_into_mappings_and_replaces_the_rest() -> None:
    base = {"a": {"b": 1, "c": [1, 2]}, "d": 3}
    merged = deep_merge(base, {"a": {"c": [9]}, "e": {"f": 1}})
    assert merged == {"a": {"b": 1, "c": [9]}, "d": 3, "e": {"f": 1}}
    assert base == {"a": {"b": 1, "c": [1, 2]}, "d": 3}  # untouched


def test_arm_spec_is_the_base_spec_with_the_override_merged(tmp_path: Path) -> None:
    two = (
        "{name: gs-rep-plain-head, model: yolov8n-seg-gs-rep, spec: {head: {share_repconv: false}}}"
    )
    cfg = load_ablation_config(write_config(tmp_path, f"[yolov8n-seg, {M16}, {two}]"))
    plain, m16, flat = cfg.variants
    assert plain.plain and not m16.plain and not flat.plain
    assert plain.model_spec() == get_spec("yolov8n-seg")
    base, spec = get_spec("yolov8n-seg").to_dict(), m16.model_spec().to_dict()
    assert spec["head"]["num_masks"] == 16 and spec["name"] == "n-m16"
    # everything else is the base spec's, nested fields included
    assert spec | {"name": base["name"], "head": spec["head"] | {"num_masks": 32}} == base
    rep = flat.model_spec()
    assert rep.head.share_repconv is False and rep.head.kind == "shared-rep"
    assert rep.neck == get_spec("yolov8n-seg-gs-rep").neck == "slim"
    assert cfg.to_dict()["variants"][1] == {
        "name": "n-m16",
        "model": "yolov8n-seg",
        "spec": {"head": {"num_masks": 16}},
    }


@pytest.mark.parametrize(
    ("variants", "needle"),
    [
        (
            "[{name: x1, model: yolov8n-seg, spec: {head: {bogus: 1}}}]",
            "arm x1: spec.head: unknown field(s) ['bogus']",
        ),
        (
            "[{name: x1, model: yolov8n-seg, spec: {colour: red}}]",
            "arm x1: spec: unknown field(s) ['colour']",
        ),
        (
            "[{name: x1, model: yolov8n-seg, spec: {head: {num_masks: many}}}]",
            "arm x1: spec.head.num_masks: expected int",
        ),
        (
            "[{name: x1, model: yolov8n-seg, spec: {neck: wide}}]",
            "neck='wide' is not one of",
        ),
        ("[{name: x1, model: yolov8q-seg}]", "variants[0] (x1): model 'yolov8q-seg' unknown"),
        ("[{name: x1, modle: yolov8n-seg}]", "variants[0]: unknown field(s) ['modle']"),
        (f"[{M16}, {M16}]", "variants ['n-m16'] repeat"),
        ("[yolov8n-seg, yolov8n-seg]", "variants ['yolov8n-seg'] repeat"),
        ("[{name: a/b, model: yolov8n-seg}]", "'name' must be a folder-safe string"),
        (
            "[{name: yolov8n-seg-gs, model: yolov8n-seg, spec: {neck: slim}}]",
            "is a zoo variant; give the override its own name",
        ),
        ("[{name: x1, model: yolov8n-seg, spec: {name: y}}]", "drop spec.name"),
        ("[]", "variants must be a non-empty list"),
    ],
)
def test_bad_arms_are_one_line_errors_naming_file_and_arm(
    tmp_path: Path, variants: str, needle: str
) -> None:
    path = write_config(tmp_path, variants)
    with pytest.raises(SlimsegError) as err:
        load_ablation_config(path)
    message = str(err.value)
    assert needle in message and str(path) in message and "\n" not in message


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("seeds", "[0, 0]", "seeds must be a non-empty list of distinct ints"),
        ("seeds", "[a]", "seeds[0]: expected int"),
        ("metrics", "[coco, nope]", "metrics ['nope'] unknown; known: coco"),
        ("metrics", "[]", "metrics must list 'coco'"),
        ("bench", "{imgsz: [64, 100]}", "bench.imgsz must be one or more distinct multiples"),
        ("bench", "{masks: yes please}", "bench.masks: expected bool"),
    ],
)
def test_bad_seeds_metrics_bench(tmp_path: Path, field: str, value: str, needle: str) -> None:
    path = write_config(tmp_path, **{field: value})
    with pytest.raises(SlimsegError) as err:
        load_ablation_config(path)
    assert needle in str(err.value) and str(path) in str(err.value)


def test_hash_covers_arms_and_seeds_and_layout_follows_seeds(tmp_path: Path) -> None:
    plain = load_ablation_config(write_config(tmp_path, "[yolov8n-seg]"))
    as_mapping = load_ablation_config(write_config(tmp_path, "[{name: yolov8n-seg}]"))
    assert as_mapping.hash == plain.hash and as_mapping.variants[0].plain
    base = load_ablation_config(write_config(tmp_path))
    seeded = load_ablation_config(write_config(tmp_path, seeds="[0, 1]"))
    other = load_ablation_config(
        write_config(tmp_path, M16.replace("16", "8").join(["[yolov8n-seg, ", "]"]))
    )
    assert len({plain.hash, base.hash, seeded.hash, other.hash}) == 4
    one = load_ablation_config(write_config(tmp_path, bench="{imgsz: 64, runs: 2}"))
    assert one.bench_sizes == (64,) and base.bench_sizes == (64,)  # default: the train imgsz
    out = tmp_path / "out"
    assert [r.dir for r in sweep_runs(base, out)] == [
        out / "variants" / "yolov8n-seg",
        out / "variants" / "n-m16",
    ]
    runs = sweep_runs(seeded, out)
    assert [(r.arm.name, r.seed) for r in runs] == [  # seed-major: a cut sweep has every arm
        ("yolov8n-seg", 0),
        ("n-m16", 0),
        ("yolov8n-seg", 1),
        ("n-m16", 1),
    ]
    assert runs[3].dir == out / "variants" / "n-m16" / "seed-1"


def test_mean_spread_is_half_the_range() -> None:
    assert mean_spread([0.2, 0.5, 0.3]) == (pytest.approx(1 / 3), pytest.approx(0.15))
    assert mean_spread([0.4]) == (0.4, 0.0)
    assert all(math.isnan(v) for v in mean_spread([0.4, math.nan]))


@dataclass(frozen=True)
class DetectedFraction:
    """Fraction of val images on which the run's best weights keep a detection at
    ``conf`` (the torch predictor path), and whether the weights have the arm's mask count."""

    name: str = "detected"
    columns: tuple[str, ...] = ("val_detected", "masks_match")
    conf: float = 0.001

    def __call__(self, run_dir: Path, spec: ModelSpec, data_cfg: DataConfig) -> dict[str, float]:
        _, info = run_weights(run_dir)
        predictor = Predictor.from_path(run_dir / "weights" / "best.pt", threads=1)
        val = CocoDataset.from_config(data_cfg, "val")
        hits = [len(predictor.predict(val[i].image, conf=self.conf).boxes) > 0 for i in range(4)]
        same = info.spec.head.num_masks == spec.head.num_masks
        return {"val_detected": sum(hits) / len(hits), "masks_match": float(same)}


def test_a_metric_returning_other_columns_is_refused(tmp_path: Path) -> None:
    @dataclass(frozen=True)
    class Wrong:
        name: str = "wrong"
        columns: tuple[str, ...] = ("a",)

        def __call__(self, run_dir: Path, spec: ModelSpec, data_cfg: DataConfig) -> dict:
            return {"b": 1.0}

    with pytest.raises(SlimsegError, match=r"'wrong' returned \['b'\], declared \['a'\]"):
        score_run([Wrong()], tmp_path, get_spec("yolov8n-seg"), None)  # type: ignore[arg-type]


def test_latency_at_two_sizes_with_mask_postprocessing(tmp_path: Path) -> None:
    model = build_model("yolov8n-seg", num_classes=2).eval()
    info = WeightsInfo(spec=model.spec, names=["a", "b"], mobility=[0.5, 1.0])
    frame = np.random.default_rng(0).integers(0, 256, (48, 80, 3), dtype=np.uint8)
    opts = BenchOptions(runs=2, warmup=1, threads=1, imgsz=(64, 96), masks=True, conf=0.001)
    ms = bench_latency(model, info, tmp_path, 64, opts, frame)
    assert list(ms) == latency_columns((64, 96), True)
    assert list(ms)[:3] == ["ms_net@64", "ms_post@64", "dets@64"]
    assert all(math.isfinite(v) and v > 0 for v in ms.values())
    # random weights at conf 0.001 keep some boxes: the mask assembly ran on each
    assert ms["dets@64"] >= 1 and ms["dets@96"] >= 1
    assert (tmp_path / "model.onnx").is_file() and (tmp_path / "model-96.onnx").is_file()
    net_only = bench_latency(model, info, tmp_path, 64, BenchOptions(1, 0, 1, (64,)), frame)
    assert list(net_only) == ["ms_net@64"]


def test_report_with_seeds_shows_mean_spread_and_per_seed_rows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(ROW_METRICS, "detected", DetectedFraction())
    bench = "{imgsz: [64, 96], masks: true, runs: 2, warmup: 1, threads: 1}"
    path = write_config(tmp_path, seeds="[0, 1]", metrics="[coco, detected]", bench=bench)
    cfg = load_ablation_config(path)

    def row(variant: str, seed: int, box: float) -> dict:
        r = {"variant": variant, "model": "yolov8n-seg", "seed": seed, "epochs": 1}
        r |= {"box_map50_95": box, "seg_map50_95": box / 2, "box_map50": 2 * box}
        r |= {"seg_map50": box, "val_detected": 0.5 + seed / 4, "masks_match": 1.0}
        r |= {"best_epoch": 1, "train_img_s": 10.0 + seed, "latency_ms": 3.0}
        r |= {k: 3.0 + seed for k in latency_columns((64, 96), True)}
        r |= {"gflops": 1.0, "gflops_paper": 1.1, "gflops_imgsz": 64, "gradients": 10}
        r |= {"params": 10, "params_paper": 10, "fused_params": 9, "latency_imgsz": 64}
        r |= {"val_images": 4, "num_classes": 6, "spec_hash": "0" * 12, "git_sha": "abc"}
        return r

    rows = [row("yolov8n-seg", 0, 0.10), row("yolov8n-seg", 1, 0.13)]
    rows += [row("n-m16", 0, 0.20), row("n-m16", 1, 0.30)]
    (s1, s2) = summarize(rows, cfg)
    assert s2["box_map50_95"] == pytest.approx(0.25)
    assert s2["box_map50_95_spread"] == pytest.approx(0.05)
    assert s1["seeds"] == "0 1" and s1["runs"] == 2 and s1["dets@96"] == 3.5
    text = markdown(rows, cfg)
    assert "mean ± half the max–min range over the seeds" in text
    assert "| n-m16 | 25.0 ± 5.0 | 12.5 ± 2.5 |" in text
    assert "| n-m16 | 1 | 30.0 | 15.0 | 60.0 | 30.0 | 75.0 | 100.0 | 1 |" in text  # per seed
    assert "| n-m16 | 62.5 ± 12.5 | 100.0 ± 0.0 |" in text  # extra metrics
    assert "post ms @96" in text and "## Latency by input size" in text
    # the paper table pairs the plain zoo arm only
    assert "yolov8n-seg → yolov8s-seg" in text and "n-m16 →" not in text


@pytest.mark.slow
def test_two_arms_two_seeds_sweep_resumes_after_its_first_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(ROW_METRICS, "detected", DetectedFraction())
    bench = "{imgsz: [64, 96], masks: true, conf: 0.001, runs: 2, warmup: 1, threads: 1}"
    path = write_config(tmp_path, seeds="[0, 1]", metrics="[coco, detected]", bench=bench)
    cfg, out = load_ablation_config(path), tmp_path / "sweep"
    first = out / "variants" / "yolov8n-seg" / "seed-0"

    class Interrupt(Exception):
        pass

    def stop_after_first_row(line: str) -> None:
        if " -> " in line:  # the first run's row and reports are written
            raise Interrupt(line)

    with pytest.raises(Interrupt):
        run_sweep(cfg, out, progress=False, log=stop_after_first_row)
    kept = (first / "row.json").read_bytes()
    kept_mtime = (first / "row.json").stat().st_mtime_ns
    assert not (out / "variants" / "yolov8n-seg" / "seed-1" / "row.json").exists()

    lines: list[str] = []
    rows = run_sweep(cfg, out, progress=False, log=lines.append)
    assert lines[0] == "[1/4] yolov8n-seg/seed-0: done earlier, row kept"
    assert "[4/4] n-m16/seed-1: training (1 epochs, seed 1)" in lines
    assert (first / "row.json").read_bytes() == kept
    assert (first / "row.json").stat().st_mtime_ns == kept_mtime
    assert [(r["variant"], r["seed"]) for r in rows] == [  # seed-major
        ("yolov8n-seg", 0),
        ("n-m16", 0),
        ("yolov8n-seg", 1),
        ("n-m16", 1),
    ]
    with (out / "results.csv").open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == 4 and [r["seed"] for r in table] == ["0", "0", "1", "1"]
    with (out / "summary.csv").open() as f:
        summary = {r["variant"]: r for r in csv.DictReader(f)}
    a, b = (float(r["box_map50_95"]) for r in table[1::2])  # n-m16, seeds 0 and 1, by hand
    got = summary["n-m16"]
    assert float(got["box_map50_95_mean"]) == pytest.approx((a + b) / 2, abs=1e-6)
    assert float(got["box_map50_95_spread"]) == pytest.approx(abs(a - b) / 2, abs=1e-6)
    d0, d1 = (float(r["val_detected"]) for r in table[0::2])
    assert float(summary["yolov8n-seg"]["val_detected_mean"]) == pytest.approx((d0 + d1) / 2)
    assert summary["n-m16"]["seeds"] == "0 1" and summary["n-m16"]["runs"] == "2"

    m16 = out / "variants" / "n-m16"
    spec = load_spec(m16 / "seed-0" / "spec.yaml")  # the spec it trained with, loadable
    assert (spec.name, spec.head.num_masks, spec.num_classes) == ("n-m16", 16, 6)
    assert not (first / "spec.yaml").exists()  # plain zoo arms: the shipped spec, no copy
    for seed in (0, 1):
        row = json.loads((m16 / f"seed-{seed}" / "row.json").read_text())
        _, info = run_weights(m16 / f"seed-{seed}")
        assert row["seed"] == info.train_config["seed"] == seed
        assert row["spec_hash"] == info.spec.hash == spec.hash and row["masks_match"] == 1.0
        for size in (64, 96):
            assert row[f"ms_net@{size}"] > 0 and row[f"ms_post@{size}"] > 0
            assert row[f"dets@{size}"] >= 1  # conf 0.001: the mask assembly ran
        assert row["latency_ms"] == row["ms_net@64"] and row["latency_imgsz"] == 64
        assert (m16 / f"seed-{seed}" / "model-96.onnx").is_file()
    w0 = run_weights(m16 / "seed-0")[0].state_dict()
    w1 = run_weights(m16 / "seed-1")[0].state_dict()
    assert any(not np.array_equal(w0[k].numpy(), w1[k].numpy()) for k in w0)  # seeds differ
    assert row["params"] < rows[0]["params"]  # 16 mask coefficients: a smaller head
    text = (out / "results.md").read_text()
    assert "± " in text and "## Per-seed rows" in text and "n-m16 →" not in text
    assert (out / "results.png").stat().st_size > 10_000
