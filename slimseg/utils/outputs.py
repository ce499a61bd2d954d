"""What a command may write, and where its inputs may come from: the one home of both rules.

**Outputs: a command writes only what it owns.** This module decides and never writes: the
writing (files, folder outputs, the manifest itself) is :mod:`slimseg.utils.atomic`, which
builds on these checks.

* Every folder output slimseg builds (:func:`slimseg.utils.atomic.staged_dir`, ``data synth``,
  ``ablate``) holds a manifest, :data:`MANIFEST`, listing the top-level entries slimseg wrote
  there, each with its size and content digest (:mod:`slimseg.utils.manifest`), and the
  command that wrote them. An existing ``--out`` folder may be replaced only when everything
  in it is listed and unchanged (or it is empty): :func:`claim_folder` refuses any other in
  one line naming the foreign, changed or unconfined entries, before the work starts.
* An output that is also an input (``export --weights best.pt --out best.pt``, ``predict
  --source X --out X``, ``val --save-json`` onto the split's own annotations) is refused by
  :func:`refuse_inputs`; a folder output may not contain an input either (it is replaced
  whole).
* A single file that would land on an existing file the command does not recognise as its
  own (``export``'s ``.json`` sidecar over ``train/annotations.json``) is refused by
  :func:`claim_file`.
* Names derived from inputs never collide (:func:`unique_stems`); names that become paths
  (sweep, arm and run names) are checked by :func:`check_folder_name`.

**Inputs: paths read from a data file stay inside its root.** :func:`inside_root` refuses a
path from a data file (``annotations.json`` ``file_name``, ``rgb.txt``/``depth.txt``,
``data.yaml`` splits) that is absolute or climbs out of its root with ``..``, unless the user
passed ``slimseg --allow-outside-root`` (which sets :data:`ALLOW_OUTSIDE_ENV`). The check is
lexical: a symlink the user placed inside the root is the user's choice and is followed.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Callable, Collection, Iterable, Mapping
from pathlib import Path

from slimseg.errors import SlimsegError
from slimseg.utils.manifest import MANIFEST, entry_problems, read_entries
from slimseg.utils.text import printable

ALLOW_OUTSIDE_ENV = "SLIMSEG_ALLOW_OUTSIDE_ROOT"  # set by `slimseg --allow-outside-root`
ALLOW_OUTSIDE_FLAG = "--allow-outside-root"
FOLDER_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")  # names that become folders
_SHOWN = 4  # foreign entries named in a refusal


def read_manifest(folder: Path) -> set[str] | None:
    """The names ``folder``'s manifest lists (confined or not: :func:`claim_folder` checks),
    or ``None`` without a readable one."""
    entries = read_entries(folder)
    return None if entries is None else set(entries)


def foreign_entries(folder: Path) -> list[str]:
    """Top-level entries of an existing ``folder`` that slimseg's manifest does not list
    (everything when there is no manifest), sorted."""
    owned = read_manifest(folder) or set()
    return sorted(p.name for p in folder.iterdir() if p.name != MANIFEST and p.name not in owned)


def _shown(names: list[str]) -> str:
    more = f" (+{len(names) - _SHOWN} more)" if len(names) > _SHOWN else ""
    return ", ".join(printable(n) for n in names[:_SHOWN]) + more


def named_folder(path: str | Path, option: str = "--out") -> Path:
    """``path`` as a folder output that can be built beside itself and moved into place:
    ``SlimsegError`` for an empty path, ``.``, ``..`` or ``/`` (the current folder, a parent
    or the root would be replaced whole, or written into among the user's files)."""
    text = os.fspath(path)
    if not text.strip() or Path(text).name in ("", ".", ".."):
        raise SlimsegError(
            f"{option} {text!r}: give a named folder (e.g. {option} runs/out), not the current, "
            "a parent or the root folder"
        )
    return Path(text)


def claim_folder(path: str | Path, option: str = "--out", own: Collection[str] = ()) -> None:
    """``SlimsegError`` (one line) unless ``path`` is new, an empty folder or a folder whose
    every entry slimseg wrote and nobody changed since; a file where the folder goes is
    refused too. ``own``: the names the calling command writes, which may take over an entry
    listed without a record (a resumable sweep's, an older slimseg's manifest)."""
    path = named_folder(path, option)
    if not os.path.lexists(path):
        return
    if not path.is_dir():
        raise SlimsegError(f"{option} {path} is a file, not a folder: give a folder path")
    foreign = foreign_entries(path)
    if foreign:
        raise SlimsegError(
            f"{option} {path} holds files slimseg did not write ({_shown(foreign)}): give a new "
            "or empty folder (slimseg replaces its own outputs only)"
        )
    problems = entry_problems(path, own)
    if problems:
        raise SlimsegError(
            f"{option} {path}: its {MANIFEST} lists entries slimseg may not remove "
            f"({_shown(problems)}): give a new or empty folder, or clear this one yourself"
        )


def _same_or_inside(a: Path, b: Path) -> bool:
    """``a`` is ``b`` or lies inside it (both resolved)."""
    return a == b or b in a.parents


def refuse_inputs(
    out: str | Path,
    option: str,
    inputs: Mapping[str, str | Path | Iterable[str | Path] | None],
    folder: bool = False,
) -> None:
    """``SlimsegError`` when output ``out`` is one of ``inputs`` (``{option: path(s)}``) or,
    with ``folder`` (an output replaced whole), contains one. Paths are compared resolved."""
    target = Path(out).expanduser().resolve()
    for name, value in inputs.items():
        if value is None:
            continue
        values = [value] if isinstance(value, str | Path) else list(value)
        for v in values:
            try:
                src = Path(v).expanduser().resolve()
            except (ValueError, OSError):  # a name no file can have (a lone surrogate, NUL)
                continue
            if src == target or (folder and _same_or_inside(src, target)):
                raise SlimsegError(
                    f"{option} {out} would overwrite the input {name} {v}: write the output "
                    "somewhere else"
                )


def claim_file(
    path: str | Path, option: str, ours: Callable[[Path], bool], what: str = "output"
) -> None:
    """``SlimsegError`` when ``path`` exists and ``ours(path)`` does not recognise it as a
    file this command writes (``what`` names the output in the message)."""
    path = Path(path)
    if os.path.lexists(path) and (path.is_dir() or not ours(path)):
        raise SlimsegError(
            f"{option}: its {what} {path} exists and is not one slimseg wrote: move it, or "
            "choose another output name"
        )


def json_with(path: Path, kind: type, key: str | None = None) -> bool:
    """``path`` parses as JSON of type ``kind`` (and, for a dict, holds ``key``): how a
    command recognises a JSON file of its own before replacing it."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, kind) and (key is None or key in data)


def unique_stems(stems: list[str], suffixes: list[str]) -> list[str]:
    """Output stems for inputs named ``stems`` (with file ``suffixes``, e.g. ``.png``) that
    never collide, case-insensitively: a repeated stem gets its suffix (``a_png``), and a name
    still taken gets ``_2``, ``_3`` ... (``a.png`` + ``a.jpg`` + ``a_png.png``: ``a_png_2``,
    ``a_jpg``, ``a_png``). Order is kept; a unique stem stays as it is."""
    counts: dict[str, int] = {}
    for s in stems:
        counts[s.casefold()] = counts.get(s.casefold(), 0) + 1
    wanted = [
        f"{s}_{x.lstrip('.').lower()}" if counts[s.casefold()] > 1 and x else s
        for s, x in zip(stems, suffixes, strict=True)
    ]
    taken = {w.casefold() for w, s in zip(wanted, stems, strict=True) if counts[s.casefold()] == 1}
    out: list[str] = []
    for w, s in zip(wanted, stems, strict=True):
        name, n = w, 1
        if counts[s.casefold()] > 1:  # the plain stems keep their names; renamed ones yield
            while name.casefold() in taken:
                n += 1
                name = f"{w}_{n}"
        taken.add(name.casefold())
        out.append(name)
    return out


def check_folder_name(name: object, where: str, field: str = "name") -> str:
    """``name`` when it is safe as one folder name (letters, digits, ``. _ -``, not starting
    with ``.``: no ``/``, no ``..``, nothing absolute); else ``SlimsegError`` naming ``where``
    and ``field``."""
    if not isinstance(name, str) or not FOLDER_NAME.fullmatch(name):
        raise SlimsegError(
            f"{where}: '{field}' must be a folder-safe string (letters, digits, . _ -), got "
            f"{name!r}"
        )
    return name


def outside_allowed() -> bool:
    """``slimseg --allow-outside-root`` given (or :data:`ALLOW_OUTSIDE_ENV` set to 1)."""
    return os.environ.get(ALLOW_OUTSIDE_ENV, "") not in ("", "0")


def escapes_root(value: str | Path) -> bool:
    """A relative path from a data file that is absolute or climbs out of the folder it is
    relative to (``../x``, ``a/../../x``), and outside paths are not allowed."""
    if outside_allowed():
        return False
    p = Path(value).expanduser()
    norm = os.path.normpath(p)
    return p.is_absolute() or norm == os.pardir or norm.startswith(os.pardir + os.sep)


def inside_root(root: str | Path, value: str | Path, where: str) -> Path:
    """``root / value`` for a path read from a data file (``where``: the file and field).

    ``SlimsegError`` when ``value`` is absolute or climbs out of ``root`` with ``..`` (the
    comparison is lexical, after ``~`` expansion), unless outside paths are allowed
    (:func:`outside_allowed`)."""
    root = Path(root)
    p = Path(value).expanduser()
    joined = p if p.is_absolute() else root / p
    if outside_allowed():
        return joined
    base = os.path.normpath(os.path.abspath(root.expanduser()))
    full = os.path.normpath(os.path.abspath(joined))
    if full != base and not full.startswith(base.rstrip(os.sep) + os.sep):
        raise SlimsegError(
            f"{where}: {str(value)!r} lies outside {root}: paths in a data file stay inside "
            f"its root (pass slimseg {ALLOW_OUTSIDE_FLAG} to allow it)"
        )
    return joined
