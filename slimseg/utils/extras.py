"""The optional dependency groups (``pip install 'slimseg[train]'``) and the one line that
says which to install when a feature needs one that is missing.

The core install (``pip install slimseg``) is the runtime: numpy, OpenCV, onnxruntime, PyYAML,
tqdm, Pillow and pycocotools. Training, export and evaluation need the ``train`` extra; its
top-level modules are listed here so that a ``ModuleNotFoundError`` for one of them becomes
that line.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from slimseg.errors import SlimsegError

TRAIN_EXTRA = "train"
#: top-level modules of the ``train`` extra (pyproject.toml ``[project.optional-dependencies]``)
TRAIN_MODULES = frozenset(
    {
        "torch",
        "torchvision",
        "lightning",
        "albumentations",
        "tensorboard",
        "onnx",
        "onnxslim",
        "matplotlib",
    }
)


def is_train_module(name: str | None) -> bool:
    """Whether module ``name`` (``torch.nn`` or ``torch``) comes with the ``train`` extra."""
    return bool(name) and name.split(".")[0] in TRAIN_MODULES


def install_command(extra: str) -> str:
    """``pip install 'slimseg[<extra>]'``: the one spelling of every install hint."""
    return f"pip install 'slimseg[{extra}]'"


def train_hint(what: str) -> str:
    """``<what> needs the training stack: pip install 'slimseg[train]'``."""
    return f"{what} needs the training stack: {install_command(TRAIN_EXTRA)}"


@contextmanager
def needs_train(what: str) -> Iterator[None]:
    """Imports in the block that miss a module of the ``train`` extra raise a
    :class:`SlimsegError` with :func:`train_hint` (``what``: the feature, e.g. ``.pt weights``)."""
    try:
        yield
    except ModuleNotFoundError as exc:
        if not is_train_module(exc.name):
            raise
        raise SlimsegError(train_hint(what)) from exc
