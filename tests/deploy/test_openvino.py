"""OpenVINO's cases (``openvino_cases.py``: every export kind against onnxruntime at f32, the
end-to-end names and shapes, bf16 only when asked, the INT8 kernel check, the CLI's
``--backend openvino``) run in a pytest process of their own.

Why: in one process, OpenVINO's CPU plugin loaded after the INT8 tests
(``tests/deploy/test_int8.py``) made the parent segfault at a later fork
(``subprocess.run`` in ``tests/dynamic/test_chain_config.py``: exit 139, no traceback);
either file alone, or OpenVINO without them, does not. Its own process keeps the rest of the
suite's forks safe."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("openvino")  # the openvino extra (make installs it, so CI runs these)

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_openvino_cases_in_a_process_of_their_own() -> None:
    cases = Path(__file__).with_name("openvino_cases.py")
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(cases)],
        capture_output=True, text=True, timeout=1200, cwd=ROOT,
    )  # fmt: skip
    tail = (run.stdout + run.stderr)[-6000:]
    assert run.returncode == 0, tail
    assert " passed" in run.stdout and "skipped" not in run.stdout.splitlines()[-1], tail
