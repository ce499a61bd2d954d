"""No two files of ``slimseg/`` import each other, directly or round a longer circle (issue #59).

Every import statement counts: at the top of a module, inside a function, under
``TYPE_CHECKING``. A circle hidden in a function is still a circle: the two files cannot be
understood, tested or moved apart. ``pyproject.toml``'s import-linter contracts name the order
inside the packages whose circles were broken; this test finds any circle anywhere.

An import of a package (its ``__init__.py``) is not an edge: importing any module of a package
runs its ``__init__``, so counting those would make every package that re-exports one of its
modules a circle. ``from pkg import name`` counts as an import of ``pkg.name`` when that is a
module, else of ``pkg``.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator, Mapping
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Circles allowed, each as its sorted modules (``slimseg.`` dropped): none since issue #59. A
# new circle is a failure, never an entry here.
ALLOWED: frozenset[tuple[str, ...]] = frozenset()


def modules(package: Path) -> dict[str, Path]:
    """Every ``.py`` file under ``package`` by dotted module name (``pkg.sub.mod``; a package
    by its own name, its ``__init__.py`` as the file)."""
    found = {}
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(package.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def _imported_names(tree: ast.AST, module: str, is_package: bool) -> Iterator[str]:
    """The dotted names every import statement anywhere in ``tree`` may refer to (for ``from
    X import a``: both ``X.a`` and ``X``); relative imports made absolute."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                here = module.split(".") if is_package else module.split(".")[:-1]
                anchor = here[: len(here) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            yield base
            yield from (f"{base}.{alias.name}" for alias in node.names)


def import_graph(mods: Mapping[str, Path]) -> dict[str, set[str]]:
    """``{module: modules it imports}`` among ``mods``; an import is resolved to its longest
    dotted prefix that is one of ``mods``, and one resolving to a package is left out."""

    def resolve(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        targets = {resolve(n) for n in _imported_names(tree, name, is_package)}
        graph[name] = {t for t in targets if t and t != name and mods[t].name != "__init__.py"}
    return graph


def circles(graph: Mapping[str, set[str]]) -> set[tuple[str, ...]]:
    """The strongly connected components of ``graph`` with more than one module, each as its
    sorted modules (Tarjan's algorithm, iterative: no recursion limit)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: set[tuple[str, ...]] = set()
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, edges = work[-1]
            nxt = next(edges, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    comp.append(member)
                    if member == node:
                        break
                if len(comp) > 1:
                    found.add(tuple(sorted(comp)))
    return found


def package_circles(package: Path) -> set[tuple[str, ...]]:
    """The circles of files in ``package``, module names relative to it (``data.tum``)."""
    prefix = package.name + "."
    return {
        tuple(m.removeprefix(prefix) for m in comp)
        for comp in circles(import_graph(modules(package)))
    }


def _show(found: set[tuple[str, ...]]) -> str:
    return "\n".join("  " + " <-> ".join(c) for c in sorted(found)) or "  (none)"


def test_no_new_file_circle() -> None:
    found = package_circles(ROOT / "slimseg")
    new = found - ALLOWED
    assert not new, (
        "files of slimseg/ import each other (break the circle: move the shared piece to the "
        f"module both need, or invert the dependency); never add it to ALLOWED:\n{_show(new)}"
    )


def test_allow_list_only_names_live_circles() -> None:
    gone = ALLOWED - package_circles(ROOT / "slimseg")
    assert not gone, f"these circles are broken: delete them from ALLOWED:\n{_show(gone)}"


def _write(root: Path, files: Mapping[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    return root / "pkg"


def test_checker_sees_function_level_type_checking_and_relative_imports(tmp_path: Path) -> None:
    pkg = _write(
        tmp_path,
        {
            "pkg/__init__.py": "from pkg.a import A\n",  # a package import is no edge
            "pkg/a.py": "from pkg.b import B\nA = 1\n",
            "pkg/b.py": "def f():\n    from pkg import a\n    return a\nB = 2\n",
            "pkg/sub/__init__.py": "",
            "pkg/sub/c.py": (
                "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import d\n"
            ),
            "pkg/sub/d.py": "import pkg.sub.e\n",
            "pkg/sub/e.py": "from ..sub.c import X\n",
            "pkg/f.py": "import pkg.a\n",  # imports a circle, is not in one
        },
    )
    assert package_circles(pkg) == {("a", "b"), ("sub.c", "sub.d", "sub.e")}


def test_checker_finds_no_circle_in_a_chain(tmp_path: Path) -> None:
    pkg = _write(
        tmp_path,
        {
            "pkg/__init__.py": "",
            "pkg/a.py": "import pkg.b\n",
            "pkg/b.py": "def f():\n    from pkg.c import g\n",
            "pkg/c.py": "import os\n",
        },
    )
    assert import_graph(modules(pkg)) == {
        "pkg": set(),
        "pkg.a": {"pkg.b"},
        "pkg.b": {"pkg.c"},
        "pkg.c": set(),
    }
    assert package_circles(pkg) == set()
