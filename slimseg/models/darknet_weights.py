"""Read and write darknet ``.weights`` files for ``Darknet19YOLOv3``.

File layout (little-endian, darknet ``src/parser.c``):

* header: ``int32 major, minor, revision``, then ``seen`` as ``uint64`` when
  ``major*10 + minor >= 2`` (and both < 1000), else ``int32`` — 20 or 16 bytes;
* per convolution in cfg order (``Darknet19YOLOv3.darknet_convs()``): with BatchNorm
  ``[beta, gamma, running_mean, running_var]`` (``n`` float32 each), without BatchNorm
  ``[bias]``, then the kernel ``[n, c_in/groups, kh, kw]`` (= PyTorch OIHW), float32.

Partial files (e.g. ``darknet19_448.conv.23`` = the 18 backbone convs) load up to the last
complete conv; the file size is validated before any tensor is touched, so a failed load
leaves the model unchanged.

Fused models (built with ``fused=True`` or returned by ``fuse_model``) are rejected by both
functions: a ``.weights`` file stores BatchNorm statistics that a fused conv no longer has.
Load into an unfused model, then call ``fuse_model``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.models.darknet_yolov3 import Darknet19YOLOv3
from slimseg.utils.atomic import write_bytes

_F32 = np.dtype("<f4")
_I32 = np.dtype("<i4")
_U64 = np.dtype("<u8")


class DarknetWeightsError(ValueError):
    """A ``.weights`` file does not match the model (size, header) or cannot be used."""


def _seen_dtype(major: int, minor: int) -> np.dtype:
    """darknet: ``seen`` is uint64 from version 0.2 on (and for sane major/minor), else int32."""
    if major * 10 + minor >= 2 and major < 1000 and minor < 1000:
        return _U64
    return _I32


def _conv_tensors(conv: ConvBNAct | nn.Conv2d, where: str = "") -> list[torch.Tensor]:
    """Tensors of one conv in file order: BN ``[β, γ, mean, var]`` or ``[bias]``, then weight."""
    if isinstance(conv, ConvBNAct):
        if not isinstance(conv.bn, nn.BatchNorm2d):
            raise DarknetWeightsError(
                f"{where}model is fused (BatchNorm folded) but darknet .weights hold BatchNorm "
                "statistics; use an unfused model (fused=False) and call fuse_model() afterwards"
            )
        bn = conv.bn
        return [bn.bias, bn.weight, bn.running_mean, bn.running_var, conv.conv.weight]
    if conv.bias is None:
        raise DarknetWeightsError(f"{where}linear conv {conv} has no bias; darknet expects one")
    return [conv.bias, conv.weight]


def _describe(index: int, conv: ConvBNAct | nn.Conv2d) -> str:
    c = conv.conv if isinstance(conv, ConvBNAct) else conv
    kind = "conv+BN" if isinstance(conv, ConvBNAct) else "conv+bias"
    kh, kw = c.kernel_size
    return f"conv {index} ({kind} {c.in_channels}->{c.out_channels} {kh}x{kw})"


def read_darknet_header(path: str | Path) -> tuple[tuple[int, int, int], int, int]:
    """Return ``((major, minor, revision), seen, header_bytes)`` of a ``.weights`` file."""
    path = Path(path)
    with path.open("rb") as f:
        head = f.read(20)
    return _parse_header(head, path)


def _parse_header(data: bytes, path: Path) -> tuple[tuple[int, int, int], int, int]:
    if len(data) < 12:
        raise DarknetWeightsError(
            f"{path}: {len(data)} bytes is too short for a darknet header (needs 12 bytes of "
            "version + 4 or 8 bytes of 'seen'); is this a darknet .weights file?"
        )
    major, minor, revision = (int(v) for v in np.frombuffer(data, _I32, 3, 0))
    seen_dt = _seen_dtype(major, minor)
    size = 12 + seen_dt.itemsize
    if len(data) < size:
        raise DarknetWeightsError(
            f"{path}: header of version {major}.{minor}.{revision} needs {size} bytes, file has "
            f"{len(data)}; the file is truncated or not a darknet .weights file"
        )
    seen = int(np.frombuffer(data, seen_dt, 1, 12)[0])
    return (major, minor, revision), seen, size


def _nc_hint(model: Darknet19YOLOv3, n_floats: int) -> str:
    """Suggest the num_classes a full-model file of ``n_floats`` would have, if any."""
    na = model.num_anchors
    per_output = sum(1 + h.pred.in_channels for h in (model.head_p3, model.head_p4, model.head_p5))
    fixed = sum(
        sum(t.numel() for t in _conv_tensors(c))
        for c in model.darknet_convs()
        if not (isinstance(c, nn.Conv2d) and c.bias is not None)
    )
    rest = n_floats - fixed
    if rest > 0 and rest % (na * per_output) == 0:
        nc = rest // (na * per_output) - 5
        if nc >= 1 and nc != model.num_classes:
            return f" (its size fits a full Darknet19YOLOv3 with num_classes={nc})"
    return ""


@torch.no_grad()
def load_darknet_weights(model: Darknet19YOLOv3, path: str | Path) -> int:
    """Load a darknet ``.weights`` file into ``model`` in place; return the number of convs read.

    Full files fill all 41 convs; partial files (e.g. ``*.conv.23``, 18 backbone convs) fill a
    prefix and leave later layers untouched. Raises ``DarknetWeightsError`` when the data ends
    inside a conv, has trailing bytes, the header is short, or the model is fused; the model
    is not modified in that case.
    """
    path = Path(path)
    data = path.read_bytes()
    _, _, offset = _parse_header(data, path)
    convs = model.darknet_convs()
    layout = [_conv_tensors(c, f"{path}: ") for c in convs]
    payload = len(data) - offset
    if payload == 0:
        raise DarknetWeightsError(
            f"{path}: header only, no conv data; expected the data of {_describe(0, convs[0])} "
            "or more"
        )
    if payload % 4:
        raise DarknetWeightsError(
            f"{path}: {payload} data bytes after the {offset}-byte header is not a whole number "
            "of float32 values; the file is corrupt or not a darknet .weights file"
        )

    # Validate the size against conv boundaries before touching any tensor.
    n_floats, pos, n_load = payload // 4, 0, 0
    for i, tensors in enumerate(layout):
        need = sum(t.numel() for t in tensors)
        if pos == n_floats:
            break
        if pos + need > n_floats:
            raise DarknetWeightsError(
                f"{path}: data ends inside {_describe(i, convs[i])}: needs {need * 4} bytes, "
                f"{(n_floats - pos) * 4} left after {i} complete convs"
                f"{_nc_hint(model, n_floats)}; the file is truncated or was written for another "
                f"network: use one for this model (num_classes={model.num_classes}, "
                f"{model.num_anchors} anchors/level)"
            )
        pos += need
        n_load = i + 1
    if pos != n_floats:
        raise DarknetWeightsError(
            f"{path}: {(n_floats - pos) * 4} trailing bytes after all {len(convs)} convs "
            f"({pos * 4} data bytes expected after the {offset}-byte header)"
            f"{_nc_hint(model, n_floats)}; the file is for a different network — check "
            f"num_classes (model has {model.num_classes}) and the cfg (Darknet-19 + YOLOv3 head)"
        )

    flat = np.frombuffer(data, _F32, n_floats, offset)
    pos = 0
    for tensors in layout[:n_load]:
        for t in tensors:
            n = t.numel()
            src = torch.from_numpy(flat[pos : pos + n].copy()).view(t.shape)
            t.copy_(src)
            pos += n
    return n_load


@torch.no_grad()
def save_darknet_weights(
    model: Darknet19YOLOv3,
    path: str | Path,
    cutoff: int | None = None,
    version: tuple[int, int, int] = (0, 2, 0),
    seen: int = 0,
) -> int:
    """Write ``model`` as a darknet ``.weights`` file atomically; return the convs written.

    ``cutoff``: write only the first ``cutoff`` convs (18 = backbone only, like ``*.conv.23``);
    ``None`` writes all 41. ``version`` selects the ``seen`` width (uint64 for >= 0.2, else
    int32). The file is written to a temporary file next to ``path`` and moved into place.
    """
    path = Path(path)
    convs = model.darknet_convs()
    n = len(convs) if cutoff is None else cutoff
    if not 0 <= n <= len(convs):
        raise ValueError(f"cutoff must be in [0, {len(convs)}], got {cutoff}")
    major, minor, revision = (int(v) for v in version)
    seen_dt = _seen_dtype(major, minor)
    info = np.iinfo(np.uint64 if seen_dt == _U64 else np.int32)
    if not info.min <= seen <= info.max:
        raise ValueError(f"seen={seen} does not fit the {seen_dt} field of version {version}")

    chunks = [
        np.array([major, minor, revision], _I32).tobytes(),
        np.array([seen], seen_dt).tobytes(),
    ]
    for conv in convs[:n]:
        for t in _conv_tensors(conv, f"{path}: "):
            chunks.append(t.detach().to("cpu", torch.float32).contiguous().numpy().astype(_F32))

    write_bytes(path, b"".join(c if isinstance(c, bytes) else c.tobytes() for c in chunks))
    return n
