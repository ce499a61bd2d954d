"""Shared test helpers."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from torch import nn

from slimseg.models.batchnorm_stats import batchnorm_from
from slimseg.models.registry import build_model
from slimseg.objects import Objects

ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist (`make test` runs two workers) each worker computes on one thread:
    two workers on a 2-core machine, not four threads contending for two cores."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        torch.set_num_threads(1)


def disc_scene(rng: np.random.Generator, h: int, w: int, discs: int) -> np.ndarray:
    """Float32 RGB ``[h, w, 3]`` in [0, 1]: a gradient with ``discs`` flat discs (a test
    frame that gives a random-weight model something to respond to)."""
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    img = np.stack([xx / w, yy / h, np.full_like(xx, 0.5)], -1)
    for _ in range(discs):
        cx, cy, r = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(6, min(h, w) / 3)
        img[(xx - cx) ** 2 + (yy - cy) ** 2 < r**2] = rng.random(3, dtype=np.float32)
    return img


def randomize_batchnorm(model: nn.Module, seed: int = 0) -> nn.Module:
    """Give every BatchNorm non-trivial statistics and affine params (so folding matters)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, nn.BatchNorm2d):
                n = m.num_features
                m.running_mean.copy_(torch.rand(n, generator=g) - 0.5)
                m.running_var.copy_(torch.rand(n, generator=g) * 1.5 + 0.5)
                m.weight.copy_(torch.rand(n, generator=g) + 0.5)
                m.bias.copy_((torch.rand(n, generator=g) - 0.5) * 0.6)
    return model


def class_map_weights(seq: Path, path: Path) -> Path:
    """An MSNET-T (64 px; classes person, mobility 1, and chair, 0) whose batch norms are
    fitted to the frames of the TUM folder ``seq``, saved to ``path``: a class map with a mover
    on about a quarter of each frame, for the tests that mask recordings."""
    from slimseg.data.tum import TumSequence
    from slimseg.models.checkpoint import WeightsInfo, save_weights

    tum = TumSequence(seq)
    rgb = np.stack([cv2.resize(tum.load(i)[0], (64, 64)) for i in range(len(tum))])
    torch.manual_seed(4)
    model = batchnorm_from(build_model("msnet-t", num_classes=2),
                           torch.from_numpy(rgb).permute(0, 3, 1, 2).float() / 255)  # fmt: skip
    info = WeightsInfo(model.spec, ["person", "chair"], [1.0, 0.0], train_config={"imgsz": 64})
    return save_weights(path, model, info)


_COMPLEXITY: dict[tuple, object] = {}


def measured(model: nn.Module, imgsz: int | tuple[int, int] = 640):
    """:func:`slimseg.eval.complexity.measure` of ``model``, computed once per architecture and
    input size in a session. Params, gradients and GFLOPs depend on the architecture only (the
    spec, the blocks' fused state, which parameters train), never on the weights; the 640-px
    FLOP-counting forwards are the suite's largest repeated cost (test_complexity.py,
    test_msnet.py and `slimseg info` in test_cli.py measure the same variants)."""
    from slimseg.eval.complexity import count_params, measure

    size = (imgsz, imgsz) if isinstance(imgsz, int) else tuple(imgsz)
    key = (type(model).__qualname__, model.spec.hash, model.is_fused, count_params(model), size)
    if key not in _COMPLEXITY:
        _COMPLEXITY[key] = measure(model, imgsz)
    return _COMPLEXITY[key]


def open_class_bias(model: nn.Module) -> nn.Module:
    """Zero the detect head's class-logit biases (the prior bias ~ -7 keeps every random-init
    score under any threshold)."""
    with torch.no_grad():
        for branch in model.detect.cls:
            branch[-1].bias.fill_(0.0)
    return model


def have_cpp_toolchain() -> bool:
    """cmake and a C++ compiler on PATH (the export/cpp tests build the C++ consumer)."""
    return shutil.which("cmake") is not None and (
        shutil.which("c++") is not None or shutil.which("g++") is not None
    )


@pytest.fixture(autouse=True)
def _seed() -> None:
    torch.manual_seed(0)


@pytest.fixture
def build():
    return build_model


@pytest.fixture(scope="session")
def example(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``slimseg_masks`` built from export/cpp (one unity build, -O2), once per session (the
    C++ consumer tests of test_cpp_consumer.py and test_end2end.py share it)."""
    build = tmp_path_factory.mktemp("cpp_build")
    configure = [
        "cmake", "-S", str(ROOT / "export" / "cpp"), "-B", str(build),
        "-DCMAKE_BUILD_TYPE=Release", "-DCMAKE_CXX_FLAGS_RELEASE=-O2", "-DCMAKE_UNITY_BUILD=ON",
        "-DSLIMSEG_TESTS=OFF",  # the library's ctest suite: tests/deploy/test_cpp_package.py
    ]  # fmt: skip
    subprocess.run(configure, check=True, capture_output=True)
    subprocess.run(["cmake", "--build", str(build), "-j", "2"], check=True, capture_output=True)
    return build / "slimseg_masks"


def frame_objects(boxes, classes, masks, hw, scores=None) -> Objects:
    """A frame's :class:`~slimseg.objects.Objects` from its columns (scores: all 1 if None)."""
    scores = np.ones(len(classes), np.float32) if scores is None else scores
    return Objects(boxes, scores, classes, masks, hw)


def sideways_pose(camera, tx: float = 0.0):
    """A :class:`~slimseg.dynamic.epipolar.PnpPose`: the camera ``(fx, fy, cx, cy)`` moved by
    ``tx`` m along x since the earlier frame (scene points move by -tx in its frame)."""
    from slimseg.dynamic.epipolar import PnpPose

    k = np.array([[camera[0], 0, camera[2]], [0, camera[1], camera[3]], [0, 0, 1.0]])
    return PnpPose(np.zeros((3, 1)), np.array([[-tx], [0.0], [0.0]]), np.zeros((0, 3)), k)


def block_texture(hw: tuple[int, int], seed: int = 0) -> np.ndarray:
    """``uint8 [H, W, 3]`` random 4x4-px blocks: a frame ORB finds corners in everywhere."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (hw[0] // 4, hw[1] // 4, 3), dtype=np.uint8)
    return np.repeat(np.repeat(small, 4, 0), 4, 1)
