"""Reading user YAML files with one-line errors that name the file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from slimseg.errors import SlimsegError


def read_yaml(path: str | Path, what: str) -> Any:
    """Parse ``path``; a missing, unreadable or malformed file raises ``SlimsegError``.

    ``what`` names the kind of file in the message (e.g. "model spec", "data config").
    """
    path = Path(path)
    if not path.is_file():
        raise SlimsegError(f"{path}: {what} not found")
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        detail = " ".join(str(exc).split())
        raise SlimsegError(f"{path}: cannot read {what}: {detail}") from None
