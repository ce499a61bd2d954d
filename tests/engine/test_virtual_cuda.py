"""CUDA code paths on the CPU (tests/virtual_cuda.py): every model family trains one step and
validates one batch with its model, buffers, EMA and batches on a virtual ``cuda:0``, in
float32 and under float16 and bfloat16 autocast; and the device itself catches the three
kinds of device bug it exists for, at their lines."""

from __future__ import annotations

import traceback
from pathlib import Path

import pytest
import torch
from conftest import batchnorm_from, open_class_bias
from torch import nn
from virtual_cuda import VIRTUAL, VirtualCudaTensor, virtual_cuda

from slimseg.data.collate import network_input
from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.data.synth import generate
from slimseg.engine.module import ZooModule, nonfinite_ranks
from slimseg.eval.postprocess import batch_to_frame_detections
from slimseg.models.registry import detection_rows, get_spec
from slimseg.ops.nms import non_max_suppression

PRECISIONS = {"fp32": None, "fp16": torch.float16, "bf16": torch.bfloat16}
# every family in float32; under autocast one model per loss and head kind (the -gs-rep-hr
# variant: shared head, stride-2 prototypes), to keep the suite short
CASES = [
    *(
        (m, "fp32")
        for m in ("yolov8n-seg", "yolov8n", "yolov8n-seg-gs-rep-hr", "darknet19-yolov3", "msnet-t")
    ),
    *(
        (m, p)
        for p in ("fp16", "bf16")
        for m in ("yolov8n-seg-gs-rep-hr", "darknet19-yolov3", "msnet-t")
    ),
]
IMGSZ = 64


@pytest.fixture(scope="module")
def batches(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One training and one validation batch (2 images, 64 px) per target kind."""
    root = tmp_path_factory.mktemp("vcuda")
    data = load_data_config(generate(root / "ds", 2, 2, 96, seed=4, progress=False).data_yaml)
    out = {}
    for semantic in (False, True):
        dm = SegDataModule(data, IMGSZ, 2, 0, seed=0, semantic=semantic)
        dm.setup("fit")
        out[semantic] = (dm, next(iter(dm.train_dataloader())), next(iter(dm.val_dataloader())))
    out["names"] = list(data.names)
    return out


def _detecting(module: ZooModule, images: torch.Tensor) -> None:
    """Random init scores nothing: give the network image-dependent activations and open its
    class (YOLOv8) or objectness (Darknet) bias, so validation builds boxes and masks."""
    batchnorm_from(module.model, images.float() / 255)
    if module.spec.family == "yolov8":
        cls = module.model.detect.cls
        if isinstance(cls, nn.Conv2d):  # the shared head: one class conv for every level
            with torch.no_grad():
                cls.bias.fill_(0.0)
        else:
            open_class_bias(module.model)
    elif module.spec.family == "darknet-yolov3":
        with torch.no_grad():
            for head in (module.model.head_p3, module.model.head_p4, module.model.head_p5):
                head.pred.bias.view(module.model.num_anchors, -1)[:, 4:].fill_(0.0)
    module.model.train()
    module.ema.module.load_state_dict(module.model.state_dict())


def _virtual(t: object) -> bool:
    return isinstance(t, VirtualCudaTensor) and t.device == VIRTUAL


@pytest.mark.slow
@pytest.mark.parametrize(("name", "precision"), CASES)
def test_train_step_and_validation_on_a_virtual_cuda_device(
    name: str, precision: str, batches: dict
) -> None:
    dtype = PRECISIONS[precision]
    spec = get_spec(name, len(batches["names"]))
    module = ZooModule(spec.to_dict(), {"ema": True, "conf": 0.0, "max_det": 8}, batches["names"])
    dm, train_batch, val_batch = batches[module.semantic]
    _detecting(module, train_batch["images"])
    with virtual_cuda() as cuda:
        module.to(cuda)
        module.ema.module.to(cuda)  # what ZooModule.on_fit_start does
        assert all(_virtual(t) for t in [*module.parameters(), *module.buffers()])
        assert all(_virtual(t) for t in module.ema.module.state_dict().values())
        optimizer = module.configure_optimizers()
        batch = dm.transfer_batch_to_device(train_batch, cuda, 0)
        with torch.autocast("cuda", dtype=dtype or torch.float16, enabled=dtype is not None):
            outputs = module.model(network_input(batch["images"]))
            loss, _ = module.criterion(outputs, batch)
            assert nonfinite_ranks(loss) == []
        assert _virtual(loss) and loss.dtype == torch.float32
        loss.backward()
        assert all(_virtual(p.grad) for p in module.model.parameters() if p.grad is not None)
        optimizer.step()
        optimizer.zero_grad()
        module.ema.update(module.model)
        assert all(_virtual(t) for t in module.ema.module.state_dict().values())

        val = dm.transfer_batch_to_device(val_batch, cuda, 0)
        with torch.autocast("cuda", dtype=dtype or torch.float16, enabled=dtype is not None):
            module.validation_step(val, 0)  # NMS, masks, RLEs, or the confusion matrices
            ((_, results),) = module._val_results
            assert len(results) == 2
            if spec.task == "semantic":
                return
            if name != "yolov8n-seg":
                return  # NMS ran; these random-init networks score no detection here (open)
            assert sum(len(f.scores) for f in results) > 0
            if spec.task == "segment":
                assert any(r is not None for f in results for r in f.rles)
                # the dense path (frame masks, as the predictor makes them)
                model = module.eval_model
                pred, proto = model(network_input(val["images"]))
                assert pred.dtype == proto.dtype == torch.float32
                dets = non_max_suppression(detection_rows(spec.family, pred), model.num_classes)
                frames = batch_to_frame_detections(dets, proto, val["meta"])
                assert all(f.masks.shape[1:] == f.image_hw for f in frames)


# --- the device catches the bugs it is for, at their line ------------------------------------
class _Buggy(nn.Module):
    """One bug per mode, each on the line marked ``# BUG``."""

    def __init__(self, mode: str) -> None:
        super().__init__()
        self.mode = mode
        self.conv = nn.Conv2d(3, 4, 1)
        self.scale = torch.ones(4, 1, 1)  # a plain attribute: module.to() does not move it

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.conv(x)
        if self.mode == "factory":
            return y + torch.arange(y.shape[-1], dtype=y.dtype)  # BUG: no device=
        if self.mode == "unmoved":
            return y * self.scale  # BUG: the attribute stayed on the CPU
        if self.mode == "numpy":
            return torch.from_numpy(y.detach().numpy())  # BUG: no .cpu()
        return y


@pytest.mark.parametrize("mode", ["factory", "unmoved", "numpy"])
def test_device_bugs_are_caught_at_their_line(mode: str) -> None:
    model = _Buggy(mode)
    x = torch.rand(1, 3, 8, 8)
    model(x)  # on the CPU each of them runs
    with virtual_cuda() as cuda:
        model.to(cuda)
        with pytest.raises((RuntimeError, TypeError)) as caught:
            model(x.to(cuda))
    frame = [f for f in traceback.extract_tb(caught.tb) if f.filename == __file__][-1]
    assert "# BUG" in Path(__file__).read_text().splitlines()[frame.lineno - 1], frame
    assert "cuda:0" in str(caught.value)


def test_bug_free_code_runs_and_moves_back() -> None:
    model = _Buggy("none")
    with virtual_cuda() as cuda:
        model.to(cuda)
        y = model(torch.rand(1, 3, 8, 8).to(cuda))
        assert _virtual(y) and not isinstance(y.cpu(), VirtualCudaTensor)
        assert y.detach().cpu().numpy().shape == (1, 4, 8, 8)
        assert _virtual(torch.zeros(2, device=y.device)) and _virtual(y.new_zeros(2))
