"""The built wheel works outside the checkout: package data (configs) travels with it.

Builds the wheel, installs it without dependencies into a fresh virtual environment whose only
link to this one is a path entry to its third-party packages (torch & co.; no editable slimseg,
no source tree), then runs the CLI from a folder outside the checkout.
"""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _run(cmd: list[str], cwd: Path, env: dict[str, str]) -> str:
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


@pytest.mark.slow
def test_wheel_installs_and_runs_outside_the_checkout(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    dist = tmp_path / "dist"
    build = [sys.executable, "-m", "pip", "wheel", str(REPO), "--no-deps"]
    _run([*build, "--no-build-isolation", "-w", str(dist)], tmp_path, env)
    (wheel,) = dist.glob("slimseg-*.whl")

    root = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(root)
    py = root / "bin" / "python"
    site = Path(
        _run(
            [str(py), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], tmp_path, env
        ).strip()
    )
    (site / "third_party.pth").write_text(sysconfig.get_path("purelib") + "\n")
    _run(
        [sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", str(wheel)],
        tmp_path,
        env,
    )

    work = tmp_path / "user"
    work.mkdir()
    where = _run([str(py), "-c", "import slimseg; print(slimseg.__file__)"], work, env)
    assert Path(where.strip()).is_relative_to(root), where
    slimseg = [str(root / "bin" / "slimseg")]
    info = _run([*slimseg, "info", "--model", "all"], work, env)
    assert "yolov8s-seg-gs-rep" in info and "darknet19-yolov3" in info
    _run(
        [*slimseg, "data", "synth", "--out", "d", "--train", "8", "--val", "2", "--imgsz", "64"],
        work,
        env,
    )
    _run(
        [
            *slimseg,
            "train",
            "--model",
            "yolov8n-seg",
            "--data",
            "d/data.yaml",
            "--config",
            "cpu-demo",
            "--epochs",
            "1",
            "--imgsz",
            "64",
            "--batch",
            "4",
            "--out",
            "run",
            "--quiet",
        ],
        work,
        env,
    )
    assert (work / "run" / "weights" / "best.pt").is_file()
    shipped = _run([*slimseg, "ablate", "--help"], work, env)
    assert "table2-synth" in shipped
