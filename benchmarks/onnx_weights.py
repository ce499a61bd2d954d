"""The fused torch model behind a slimseg static FP32 ``.onnx``, for exports the file alone
cannot give (``--dynamic``): the benchmarks' way to every export kind of a trained model that
ships without its ``.pt`` (``../shared/models/demo-*``).

How: the zoo model the metadata names, every weight and BatchNorm statistic drawn at random
(so each value is unique), fused and exported the same way; each of its parameters is found in
that export's initializers by value, and takes the trained file's initializer of that name
(a per-level scalar the graph holds as separate constants, ``box_scale``, element by
element). The result must reproduce the file within the export's FP32 limits, else it raises.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import numpy_helper

from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.ov_checks import precision_excess
from slimseg.models.registry import build_model


def _initializers(proto: onnx.ModelProto) -> dict[str, np.ndarray]:
    return {t.name: numpy_helper.to_array(t) for t in proto.graph.initializer}


def model_from_onnx(path: Path) -> tuple[torch.nn.Module, dict]:
    """``(fused model, metadata)`` of the static FP32 slimseg export ``path``."""
    meta = json.loads(path.with_suffix(".json").read_text())
    torch.manual_seed(0)
    model = build_model(meta["model"], num_classes=len(meta["names"])).eval()
    with torch.no_grad():  # unique values, moderate activations
        for mod in model.modules():
            if isinstance(mod, torch.nn.modules.batchnorm._BatchNorm):
                mod.running_mean.uniform_(-0.1, 0.1)
                mod.running_var.uniform_(0.5, 1.5)
        for t in [*model.parameters(), *model.buffers()]:
            if t.is_floating_point() and t.numel() > 0 and t.unique().numel() < t.numel():
                t.uniform_(0.5, 1.5) if t.min() > 0 else t.uniform_(-0.1, 0.1)
    fused = model.fuse()
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp) / "probe.onnx"
        export_onnx(fused, probe, tuple(meta["imgsz"]))
        mine = _initializers(onnx.load(str(probe)))
    trained = _initializers(onnx.load(str(path)))
    if set(mine) != set(trained):
        raise ValueError(f"{path}: not the graph slimseg exports for {meta['model']} today")
    state = fused.state_dict()
    scalars = {float(v): k for k, v in mine.items() if v.size == 1}
    for key, value in state.items():
        v = value.detach().numpy()
        hits = [k for k, m in mine.items() if m.shape == v.shape and np.array_equal(m, v)]
        if len(hits) == 1:
            state[key] = torch.from_numpy(trained[hits[0]].copy())
        elif v.ndim == 1 and all(float(e) in scalars for e in v):
            state[key] = torch.tensor([float(trained[scalars[float(e)]]) for e in v])
        elif v.size:
            raise ValueError(f"{path}: {key} {tuple(v.shape)} not found in the graph")
    fused.load_state_dict(state)
    x = np.random.default_rng(0).uniform(0, 1, (1, 3, *meta["imgsz"])).astype(np.float32)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    ref = dict(
        zip([o.name for o in session.get_outputs()], session.run(None, {"images": x}), strict=True)
    )
    with torch.no_grad():
        got = dict(zip(ref, (t.numpy() for t in fused(torch.from_numpy(x))), strict=True))
    excess, worst = precision_excess(ref, got, len(meta["names"]))
    if excess > 1:
        raise ValueError(f"{path}: the recovered model is {excess:.3g}x the FP32 limits ({worst})")
    return fused, meta
