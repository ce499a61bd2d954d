"""notebooks/quickstart.ipynb runs top to bottom (shrunk by SLIMSEG_QUICK=1) and draws masks."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

nbclient = pytest.importorskip(
    "nbclient", reason="nbclient is not installed (pip install -e '.[dev]')"
)
nbformat = pytest.importorskip(
    "nbformat", reason="nbformat is not installed (pip install -e '.[dev]')"
)

pytestmark = pytest.mark.slow

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "quickstart.ipynb"


def _text(cell: dict) -> str:
    parts = []
    for out in cell.get("outputs", []):
        if out.get("output_type") == "stream":
            parts.append(out.get("text", ""))
        elif "data" in out:
            parts.append(out["data"].get("text/plain", ""))
    return "".join(parts)


def test_committed_notebook_has_no_outputs() -> None:
    nb = nbformat.read(NOTEBOOK, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code
    for cell in code:
        assert not cell.outputs and cell.execution_count is None, cell.source[:60]


def _python3_kernelspec(root: Path) -> Path:
    """A ``python3`` kernelspec running this interpreter (the venv's), found first by Jupyter."""
    spec = root / "kernels" / "python3"
    spec.mkdir(parents=True)
    argv = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
    kernel = {"argv": argv, "display_name": "Python 3 (slimseg tests)", "language": "python"}
    (spec / "kernel.json").write_text(json.dumps(kernel))
    return root


def test_quickstart_notebook_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("ipykernel", reason="ipykernel is not installed (pip install -e '.[dev]')")
    # The kernel inherits this environment: quick mode on, data and run folder in tmp_path.
    jupyter = _python3_kernelspec(tmp_path / "jupyter")
    paths = [str(jupyter), *filter(None, [os.environ.get("JUPYTER_PATH")])]
    monkeypatch.setenv("JUPYTER_PATH", os.pathsep.join(paths))
    monkeypatch.setenv("SLIMSEG_QUICK", "1")
    monkeypatch.setenv("SLIMSEG_WORKDIR", str(tmp_path / "work"))
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        timeout=300,
        kernel_name="python3",
        resources={"metadata": {"path": str(tmp_path)}},
    )
    client.execute()  # raises CellExecutionError (with the traceback) if a cell fails

    code = [c for c in nb.cells if c.cell_type == "code"]
    errors = [o for c in code for o in c.outputs if o.get("output_type") == "error"]
    assert not errors
    text = "\n".join(_text(c) for c in code)
    assert "M params" in text
    assert "synth: 16 train + 8 val images" in text
    assert "mask mAP50-95" in text
    assert "predicted" in text
    images = [o for o in code[-1].outputs if "image/png" in o.get("data", {})]
    assert images, f"the last cell displayed no image: {code[-1].outputs}"
    assert (tmp_path / "work" / "run" / "weights" / "last.pt").is_file()
