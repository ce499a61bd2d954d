"""Reference (ultralytics-layout) YOLOv8-seg state dicts mapped into slimseg models."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
import yaml
from torch import nn

import slimseg
from slimseg.errors import SlimsegError
from slimseg.models.pretrained import (
    NO_COUNTERPART,
    SHAPE_MISMATCH,
    coco80_rows_for,
    is_reference_state_dict,
    load_pretrained,
    map_reference_state_dict,
    rows_for_names,
)
from slimseg.utils.shipped import shipped_dir

COCO20 = shipped_dir("data") / "coco20.yaml"

# Our module prefix → reference layer prefix, written from the documented reference layout
# (architecture.md §1.1), independently of slimseg.models.pretrained.
_PREFIXES = [
    ("backbone.stem.0.", "model.0."),
    ("backbone.stem.1.", "model.1."),
    ("backbone.stem.2.", "model.2."),
    ("backbone.stage3.0.", "model.3."),
    ("backbone.stage3.1.", "model.4."),
    ("backbone.stage4.0.", "model.5."),
    ("backbone.stage4.1.", "model.6."),
    ("backbone.stage5.0.", "model.7."),
    ("backbone.stage5.1.", "model.8."),
    ("backbone.stage5.2.", "model.9."),
    ("neck.top_down4.", "model.12."),
    ("neck.top_down3.", "model.15."),
    ("neck.down3.", "model.16."),
    ("neck.bottom_up4.", "model.18."),
    ("neck.down4.", "model.19."),
    ("neck.bottom_up5.", "model.21."),
    ("detect.box.", "model.22.cv2."),
    ("detect.cls.", "model.22.cv3."),
    ("mask_coeffs.branches.", "model.22.cv4."),
    ("proto.", "model.22.proto."),
    ("dfl.proj.", "model.22.dfl.conv."),
]


def to_reference_name(key: str) -> str:
    for ours, ref in _PREFIXES:
        if key.startswith(ours):
            rest = key[len(ours) :]
            return ref + re.sub(r"^blocks\.(\d+)\.", r"m.\1.", rest)
    raise AssertionError(f"no reference name for {key}")


def randomized(model: nn.Module, seed: int) -> nn.Module:
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, t in model.state_dict().items():
            if name.endswith("running_var"):
                t.copy_(torch.rand(t.shape, generator=g) + 0.5)
            elif t.is_floating_point():
                t.copy_(torch.randn(t.shape, generator=g) * 0.1)
            else:
                t.fill_(int(torch.randint(1, 1000, (1,), generator=g)))
    return model.eval()


def make_reference(tmp: Path, variant: str) -> tuple[nn.Module, dict, Path]:
    """A randomised nc=80 model of ``variant``, its reference-named state dict, and its file."""
    model = randomized(slimseg.build_model(variant, num_classes=80), seed=1)
    ref = {to_reference_name(k): v.clone() for k, v in model.state_dict().items()}
    path = tmp / f"{variant}.state_dict.pt"
    torch.save(ref, path)
    return model, ref, path


@pytest.fixture(scope="module")
def ref_s(tmp_path_factory):
    return make_reference(tmp_path_factory.mktemp("ref_s"), "yolov8s-seg")


@pytest.fixture(scope="module")
def ref_n(tmp_path_factory):
    return make_reference(tmp_path_factory.mktemp("ref_n"), "yolov8n-seg")


def coco20() -> tuple[list[int], list[str]]:
    classes = yaml.safe_load(COCO20.read_text())["classes"]
    return [c["coco_id"] for c in classes], [c["name"] for c in classes]


def outputs(model: nn.Module) -> tuple[torch.Tensor, torch.Tensor]:
    x = torch.linspace(-1, 1, 3 * 64 * 64).view(1, 3, 64, 64)
    with torch.no_grad():
        return model.eval()(x)


def test_full_model_loads_every_tensor_and_matches(ref_s) -> None:
    src, ref, path = ref_s
    assert is_reference_state_dict(ref) and not is_reference_state_dict(src.state_dict())
    model = slimseg.build_model("yolov8s-seg", num_classes=80)
    report = load_pretrained(path, model)
    assert report.num_loaded == report.total == len(ref) and not report.skipped
    for k, v in src.state_dict().items():
        assert torch.equal(model.state_dict()[k], v), k
    for a, b in zip(outputs(src), outputs(model), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert f"loaded {len(ref)} of {len(ref)}" in report.format()


def test_coco20_rows_of_the_class_predictor(ref_s) -> None:
    src, ref, path = ref_s
    ids, names = coco20()
    rows = coco80_rows_for(ids)
    assert rows_for_names(names) == rows
    model = slimseg.build_model("yolov8s-seg", num_classes=20)
    report = load_pretrained(path, model, names=names)
    assert report.class_rows == rows and report.reference_classes == 80 and report.classes_loaded
    assert report.num_loaded == len(ref) and not report.skipped
    ours, theirs = model.state_dict(), src.state_dict()
    predictor = re.compile(r"^detect\.cls\.\d\.2\.")
    for k, v in theirs.items():
        if predictor.match(k):
            assert torch.equal(ours[k], v[rows]), k
        else:
            assert torch.equal(ours[k], v), k
    assert "class predictor: rows [0, 1, 2, 3, 14," in report.format()
    # the same through the in-memory API
    mapped, _ = map_reference_state_dict(
        ref, slimseg.build_model("yolov8s-seg", num_classes=20), rows
    )
    assert torch.equal(mapped["detect.cls.1.2.bias"], ref["model.22.cv3.1.2.bias"][rows])


def test_n_scale_coco20_class_branch_width_differs(ref_n) -> None:
    # n scale: class branch width max(64, min(nc, 100)) is 80 for nc=80 but 64 for nc=20
    _, ref, _ = ref_n
    model = slimseg.build_model("yolov8n-seg", num_classes=20)
    _, report = map_reference_state_dict(ref, model, coco80_rows_for(coco20()[0]))
    bad = report.skipped_by_reason()[SHAPE_MISMATCH]
    assert bad and all(s.key.startswith("model.22.cv3.") for s in bad)
    assert report.num_loaded + len(bad) == len(ref)


def test_slim_neck_loads_backbone_and_head_only(ref_n) -> None:
    src, ref, path = ref_n
    model = slimseg.build_model("yolov8n-seg-gs", num_classes=80)
    before = {k: v.clone() for k, v in model.state_dict().items() if k.startswith("neck.")}
    report = load_pretrained(path, model)
    ours, theirs = model.state_dict(), src.state_dict()
    for k, v in theirs.items():
        if not k.startswith("neck."):
            assert torch.equal(ours[k], v), k
    for k, v in before.items():
        assert torch.equal(ours[k], v), k  # neck untouched
    skipped = report.skipped_by_reason()
    assert list(skipped) == [NO_COUNTERPART]
    neck_keys = {to_reference_name(k) for k in theirs if k.startswith("neck.")}
    assert {s.key for s in skipped[NO_COUNTERPART]} == neck_keys
    assert report.num_loaded == len(ref) - len(neck_keys)
    text = report.format()
    assert "no counterpart" in text and "VoVGSCSP" in text
    detail = {s.key: s.detail for s in skipped[NO_COUNTERPART]}
    assert detail["model.16.conv.weight"].endswith("neck.down3 is GSConv")


def test_rep_head_skips_the_decoupled_branches(ref_n) -> None:
    src, ref, path = ref_n
    model = slimseg.build_model("yolov8n-seg-rep", num_classes=80)
    report = load_pretrained(path, model)
    ours = model.state_dict()
    for k, v in src.state_dict().items():
        if not k.startswith("detect."):
            assert torch.equal(ours[k], v), k
    skipped = report.skipped_by_reason()
    assert list(skipped) == [NO_COUNTERPART]
    detect = {k for k in ref if re.match(r"^model\.22\.cv[23]\.", k)}
    assert {s.key for s in skipped[NO_COUNTERPART]} == detect
    assert "SharedRepDetect" in skipped[NO_COUNTERPART][0].detail


def test_rep_head_report_says_the_class_rows_were_not_used(ref_s) -> None:
    _, ref, _ = ref_s
    model = slimseg.build_model("yolov8s-seg-rep", num_classes=20)
    _, report = map_reference_state_dict(ref, model, coco80_rows_for(coco20()[0]))
    assert not report.classes_loaded and report.reference_classes == 80
    assert "class predictor: not loaded" in report.format()


def test_fused_model_is_refused(ref_n) -> None:
    _, ref, _ = ref_n
    with pytest.raises(SlimsegError, match="fused"):
        map_reference_state_dict(ref, slimseg.build_model("yolov8n-seg", 80, fused=True))


def test_non_coco_names_skip_the_class_predictor(ref_n) -> None:
    _, ref, path = ref_n
    model = slimseg.build_model("yolov8n-seg", num_classes=80)
    init = model.state_dict()["detect.cls.0.2.weight"].clone()
    report = load_pretrained(path, model, names=[f"thing{i}" for i in range(80)])
    assert torch.equal(model.state_dict()["detect.cls.0.2.weight"], init)
    assert len(report.skipped) == 6 and report.num_loaded == len(ref) - 6


def test_nested_state_dicts_are_accepted(ref_n, tmp_path) -> None:
    _, ref, _ = ref_n
    for key in ("model", "state_dict"):
        path = tmp_path / f"{key}.pt"
        torch.save({key: ref, "epoch": 3}, path)
        report = load_pretrained(path, slimseg.build_model("yolov8n-seg", num_classes=80))
        assert report.num_loaded == len(ref)


def test_half_precision_weights_are_cast(ref_n, tmp_path) -> None:
    src, ref, _ = ref_n
    path = tmp_path / "half.pt"
    torch.save({k: v.half() if v.is_floating_point() else v for k, v in ref.items()}, path)
    model = slimseg.build_model("yolov8n-seg", num_classes=80)
    assert load_pretrained(path, model).num_loaded == len(ref)
    w = model.state_dict()["backbone.stem.0.conv.weight"]
    assert w.dtype == torch.float32
    torch.testing.assert_close(w, src.state_dict()["backbone.stem.0.conv.weight"].half().float())


def test_safetensors(ref_n, tmp_path) -> None:
    _, ref, _ = ref_n
    path = tmp_path / "w.safetensors"
    try:
        from safetensors.torch import save_file
    except ImportError:
        path.write_bytes(b"x")
        with pytest.raises(SlimsegError, match="safetensors"):
            load_pretrained(path, slimseg.build_model("yolov8n-seg", num_classes=80))
        return
    save_file({k: v.contiguous() for k, v in ref.items()}, str(path))
    report = load_pretrained(path, slimseg.build_model("yolov8n-seg", num_classes=80))
    assert report.num_loaded == len(ref)


def test_pickled_module_is_refused_with_the_conversion_hint(tmp_path) -> None:
    path = tmp_path / "yolov8s-seg.pt"
    torch.save({"model": nn.Conv2d(3, 4, 1), "epoch": -1}, path)
    with pytest.raises(SlimsegError) as err:
        load_pretrained(path, slimseg.build_model("yolov8n-seg", num_classes=80))
    msg = str(err.value)
    assert "\n" not in msg
    assert "weights_only=False" in msg and ".state_dict()" in msg
    assert "yolov8s-seg.state_dict.pt" in msg


def test_not_a_reference_state_dict(tmp_path) -> None:
    path = tmp_path / "ours.pt"
    torch.save(slimseg.build_model("yolov8n-seg", num_classes=80).state_dict(), path)
    with pytest.raises(SlimsegError, match="not a reference"):
        load_pretrained(path, slimseg.build_model("yolov8n-seg", num_classes=80))


def test_coco80_rows() -> None:
    assert coco80_rows_for([1, 37, 72, 82, 90]) == [0, 32, 62, 72, 79]
    expected = [0, 1, 2, 3, 14, 15, 16, 24, 25, 26, 28, 32, 39, 56, 62, 63, 64, 66, 67, 72]
    assert coco80_rows_for(coco20()[0]) == expected
    with pytest.raises(SlimsegError):
        coco80_rows_for([12])
    assert rows_for_names(["Cell_Phone", "tv"]) == [67, 62]
    assert rows_for_names(["person", "forklift"]) is None
