"""A virtual CUDA device for CPU-only test machines: CUDA code paths run, on the CPU.

A :class:`VirtualCudaTensor` is a real CPU tensor (autograd, autocast and every kernel are
the CPU's) that reports ``device == cuda:0`` and ``is_cuda``. Inside :func:`virtual_cuda`:

* ``.to("cuda:0")``, ``.cuda()``, ``module.to(cuda:0)`` and factories with ``device=cuda:0``
  give virtual tensors (parameters and buffers too); ``.cpu()`` / ``.to("cpu")`` give plain
  CPU tensors, as on a GPU (a copy, not a view);
* an operation that mixes a virtual tensor with a plain CPU tensor of one or more dimensions
  raises CUDA's "Expected all tensors to be on the same device" at the line that does it: a
  factory call without ``device=``, a buffer or attribute that did not move with the model.
  The exceptions are those CUDA makes: 0-dim CPU tensors (scalars), CPU index tensors, and
  ``copy_`` across devices;
* ``.numpy()`` of a virtual tensor raises CUDA's TypeError ("Use Tensor.cpu() ...");
* ``torch.autocast("cuda", ...)`` is CPU autocast (the virtual tensors are CPU tensors to the
  dispatcher), so mixed-precision code paths run with CPU autocast's float16/bfloat16 rules.

What it cannot see (docs/gpu_readiness.md): CUDA kernels and their numerics (TF32,
cuDNN algorithms, fp16 accumulation), GradScaler, NCCL, streams and asynchronous errors,
``cuda:0`` vs ``cuda:1`` (there is one virtual device), memory, and speed.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from contextlib import contextmanager

import torch
from torch.overrides import TorchFunctionMode
from torch.utils._pytree import tree_flatten, tree_map

VIRTUAL = torch.device("cuda", 0)
_T = torch.Tensor


class VirtualCudaTensor(torch.Tensor):
    """A CPU tensor that says it lives on ``cuda:0`` (see the module docstring)."""

    __torch_function__ = torch._C._disabled_torch_function_impl  # the mode does the work

    @property
    def device(self) -> torch.device:  # type: ignore[override]
        return VIRTUAL

    @property
    def is_cuda(self) -> bool:  # type: ignore[override]
        return True

    @property
    def is_cpu(self) -> bool:  # type: ignore[override]
        return False

    def numpy(self, *args: object, **kwargs: object) -> object:  # type: ignore[override]
        raise TypeError(
            "can't convert cuda:0 device type tensor to numpy. Use Tensor.cpu() to copy the "
            "tensor to host memory first."
        )

    def __deepcopy__(self, memo: dict) -> VirtualCudaTensor:
        with torch._C.DisableTorchFunction():
            new = self.as_subclass(torch.Tensor).detach().clone().as_subclass(VirtualCudaTensor)
            new.requires_grad_(self.requires_grad)
        new.__dict__ = copy.deepcopy(self.__dict__, memo)
        memo[id(self)] = new
        return new


def _names_cuda(where: object) -> bool:
    if isinstance(where, torch.Tensor):
        return isinstance(where, VirtualCudaTensor)
    if isinstance(where, (str, torch.device)):
        return torch.device(where).type == "cuda"
    return False


def _is_device(value: object) -> bool:
    return isinstance(value, torch.device) or (
        isinstance(value, str) and value.split(":")[0] in ("cpu", "cuda")
    )


# Functions that look at tensors of both kinds legitimately (or return no tensor).
_UNCHECKED = {
    torch._has_compatible_shallow_copy_type,
    torch.is_tensor,
    _T.__repr__,
    _T.__format__,
    _T.tolist,
    _T.item,
    _T.data_ptr,
    _T.__len__,
    _T.dim,
    _T.size,
    _T.numel,
    _T.__bool__,
}
# CUDA accepts CPU index tensors, and copy_ between devices.
_CPU_INDICES_OK = {_T.__getitem__, _T.index_put_, _T.index_put, _T.copy_}


class _VirtualCudaMode(TorchFunctionMode):
    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if func in (_T.to, _T.cuda, _T.cpu):
            return _move(func, args, kwargs)
        flat, _ = tree_flatten((args, kwargs))
        tensors = [t for t in flat if isinstance(t, torch.Tensor)]
        virtual = any(isinstance(t, VirtualCudaTensor) for t in tensors)
        device = kwargs.get("device")
        to_virtual = _names_cuda(device)
        if to_virtual:
            kwargs = dict(kwargs, device="cpu")
        if func in _UNCHECKED or not (virtual or to_virtual):
            return func(*args, **kwargs)
        if virtual and device is None:
            _check_same_device(func, args, tensors)
        out = func(*args, **kwargs)
        if device is not None and not to_virtual:
            return out  # an explicit CPU result, e.g. torch.zeros_like(x, device="cpu")
        inputs = {id(t) for t in tensors}  # in-place results are returned as they are
        return tree_map(
            lambda t: (
                t.as_subclass(VirtualCudaTensor)
                if isinstance(t, torch.Tensor)
                and id(t) not in inputs
                and not isinstance(t, VirtualCudaTensor)
                else t
            ),
            out,
        )


def _check_same_device(func: object, args: tuple, tensors: list[torch.Tensor]) -> None:
    if func in _CPU_INDICES_OK:
        return
    candidates = tensors
    if func is _T.__setitem__:  # the index may be on the CPU, the value may not
        candidates = [a for a in args[2:3] if isinstance(a, torch.Tensor)]
    plain = [t for t in candidates if not isinstance(t, VirtualCudaTensor) and t.dim() > 0]
    if plain:
        name = getattr(func, "__name__", str(func))
        raise RuntimeError(
            "Expected all tensors to be on the same device, but found at least two devices, "
            f"cuda:0 and cpu! (virtual CUDA device, in {name}; a CPU tensor of shape "
            f"{tuple(plain[0].shape)})"
        )


def _move(func: object, args: tuple, kwargs: dict) -> torch.Tensor:
    """``.to`` / ``.cuda`` / ``.cpu`` between the CPU and the virtual device."""
    source, rest = args[0], list(args[1:])
    plain = source.as_subclass(torch.Tensor) if isinstance(source, VirtualCudaTensor) else source
    kw = dict(kwargs)
    if func is _T.cpu:
        target, rest = False, []
    elif func is _T.cuda:
        target, rest = True, []
        kw = {k: v for k, v in kw.items() if k in ("non_blocking", "memory_format")}
    else:
        target = isinstance(source, VirtualCudaTensor)
        for i, a in enumerate(rest):
            if _is_device(a):
                target, rest[i] = _names_cuda(a), "cpu"
            elif isinstance(a, torch.Tensor):  # .to(other): other's device and dtype
                target = _names_cuda(a)
                rest[i] = a.as_subclass(torch.Tensor) if target else a
        if "device" in kw:
            target, kw["device"] = _names_cuda(kw["device"]), "cpu"
    moved = isinstance(source, VirtualCudaTensor) != target
    if moved:
        kw["copy"] = True
    out = _T.to(plain, *rest, **kw) if func is _T.to or moved else plain
    if out is plain:
        return source
    return out.as_subclass(VirtualCudaTensor) if target else out


def _autocast_on_cpu(real: type) -> type:
    """``torch.autocast`` with ``"cuda"`` meaning the CPU (where the virtual tensors live)."""

    class Autocast(real):  # type: ignore[misc, valid-type]
        def __init__(self, device_type: str, *args: object, **kwargs: object) -> None:
            super().__init__("cpu" if device_type == "cuda" else device_type, *args, **kwargs)

    return Autocast


@contextmanager
def virtual_cuda() -> Iterator[torch.device]:
    """Within: ``cuda:0`` is the virtual device (module docstring); yields it."""
    overwrite = torch.__future__.get_overwrite_module_params_on_conversion()
    autocast, amp_autocast = torch.autocast, torch.amp.autocast
    torch.__future__.set_overwrite_module_params_on_conversion(True)  # params become virtual
    torch.autocast = torch.amp.autocast = _autocast_on_cpu(autocast)
    try:
        with _VirtualCudaMode():
            yield VIRTUAL
    finally:
        torch.autocast, torch.amp.autocast = autocast, amp_autocast
        torch.__future__.set_overwrite_module_params_on_conversion(overwrite)
