"""Reading user YAML files with one-line errors that name the file, and bounded resources.

Every YAML file slimseg reads goes through :func:`load_yaml_text` (text) or :func:`read_yaml`
(a file): PyYAML's safe loader, plus limits a hostile file cannot pass. The file must be a
regular file of at most :data:`MAX_YAML_BYTES`; the document, with every alias expanded, may
hold at most :data:`MAX_YAML_NODES` nodes (aliases are shared when loaded, but anything that
walks the result, printing it or checking its keys, meets every copy: 394 bytes of nested
aliases stand for billions of nodes), and an alias may not contain itself. The budget is
counted on the composed node graph before any Python object is built.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from slimseg.errors import SlimsegError
from slimseg.utils.input_files import read_capped

MAX_YAML_BYTES = 4 << 20  # configs, specs and camera files are a few KB
MAX_YAML_NODES = 1_000_000  # after alias expansion


_SURROGATE = re.compile("[\ud800-\udfff]")


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def expanded_size(root: yaml.Node, budget: int = MAX_YAML_NODES) -> int:
    """Nodes in ``root``'s document with every alias expanded (counted once per reference,
    capped at ``budget + 1``); ``ValueError`` for an alias that contains itself, or a string
    holding an unpaired surrogate (a ``"\\ud800"`` escape: no file name can hold it)."""
    sizes: dict[int, int] = {}
    open_: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, closing = stack.pop()
        key = id(node)
        if closing:
            total = 1 + sum(sizes[id(c)] for c in _children(node))
            sizes[key] = min(total, budget + 1)
            open_.discard(key)
            continue
        if key in sizes:
            continue
        if isinstance(node, yaml.ScalarNode) and _SURROGATE.search(node.value):
            raise ValueError(  # "\ud800" escapes: not text a file name or a key can hold
                f"line {node.start_mark.line + 1}: a string holds an unpaired UTF-16 surrogate"
            )
        if key in open_:
            raise ValueError("an alias refers to a node that contains it")
        open_.add(key)
        stack.append((node, True))
        for child in _children(node):
            if id(child) in open_:
                raise ValueError("an alias refers to a node that contains it")
            if id(child) not in sizes:
                stack.append((child, False))
    return sizes[id(root)]


def load_yaml_text(text: str, where: str, budget: int = MAX_YAML_NODES) -> Any:
    """The one safe YAML loader: ``text`` parsed with PyYAML's safe constructors after the
    node budget is checked; ``SlimsegError`` naming ``where`` for malformed YAML, an alias
    that contains itself, or more than ``budget`` nodes once aliases are expanded."""
    try:
        loader = yaml.SafeLoader(text)  # its reader refuses control characters already
    except yaml.YAMLError as exc:
        raise SlimsegError(f"{where}: {' '.join(str(exc).split())}") from None
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        size = expanded_size(node, budget)
        if size > budget:
            raise SlimsegError(
                f"{where}: the YAML holds more than {budget} values once its aliases are "
                "expanded; write the values out, or use fewer aliases"
            )
        return loader.construct_document(node)
    except (yaml.YAMLError, ValueError, RecursionError) as exc:
        detail = " ".join(str(exc).split()) or "nested too deeply"
        raise SlimsegError(f"{where}: {detail}") from None
    finally:
        loader.dispose()


def read_yaml(path: str | Path, what: str) -> Any:
    """Parse ``path``; a missing, unreadable, oversized, non-regular or malformed file raises
    ``SlimsegError``.

    ``what`` names the kind of file in the message (e.g. "model spec", "data config").
    """
    path = Path(path)
    if not path.exists():
        raise SlimsegError(f"{path}: {what} not found")
    try:
        text = read_capped(path, what, MAX_YAML_BYTES).decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        detail = " ".join(str(exc).split())
        raise SlimsegError(f"{path}: cannot read {what}: {detail}") from None
    return load_yaml_text(text, f"{path}: cannot read {what}")
