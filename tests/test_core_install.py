"""The core install is the runtime: ``slimseg.Masker``, ``slimseg --help`` and the runtime's
commands import no module of the ``train`` extra; a command that needs it, missing, says so
in one line and exits 2 (checked in fresh interpreters, the train stack made unimportable)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from slimseg.cli.commands import COMMANDS
from slimseg.utils.extras import TRAIN_MODULES

ROOT = Path(__file__).resolve().parents[1]
# what the runtime must not load (the train extra, and scipy, which the core does not install)
HEAVY = sorted(TRAIN_MODULES | {"scipy"})
BLOCK = f"""
import importlib.abc, sys
class _Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in {HEAVY!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, _Block())
"""


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )


def _loaded(code: str) -> list[str]:
    """The heavy modules loaded after running ``code`` in a fresh interpreter."""
    done = _python(f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))")
    assert done.returncode == 0, done.stderr
    loaded = json.loads(done.stdout.splitlines()[-1])
    return sorted({m.split(".")[0] for m in loaded} & set(HEAVY))


def test_masker_imports_no_training_stack() -> None:
    assert _loaded("import slimseg; slimseg.Masker; slimseg.ModelRate") == []


def test_help_imports_no_command_module() -> None:
    code = (
        "import sys\nfrom slimseg.cli.main import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
        "assert not [m for m in sys.modules if m.startswith('slimseg.cli.') and "
        "m not in ('slimseg.cli.main', 'slimseg.cli.commands')], sorted(sys.modules)\n"
        "assert 'cv2' not in sys.modules and 'numpy' not in sys.modules"
    )
    assert _loaded(code) == []


@pytest.mark.parametrize("command", ["dynamic", "predict", "slam-eval", "slam"])
def test_runtime_commands_parse_without_the_training_stack(command) -> None:
    done = _python(f"{BLOCK}\nfrom slimseg.cli.main import main\nmain(['{command}', '--help'])")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: slimseg {command}")


@pytest.mark.parametrize("command", ["train", "val", "export", "info"])
def test_training_commands_say_what_to_install(command) -> None:
    run = f"import sys\nfrom slimseg.cli.main import main\nsys.exit(main(['{command}', '--help']))"
    done = _python(f"{BLOCK}\n{run}")
    assert done.returncode == 2
    assert done.stderr == (
        f"slimseg {command} needs the training stack: pip install 'slimseg[train]'\n"
    )


def test_every_command_module_takes_its_help_from_the_table() -> None:
    import importlib

    for command in COMMANDS:
        source = Path(importlib.util.find_spec(command.module).origin).read_text()
        assert f'help=COMMAND_HELP["{command.name}"]' in source, command.module


def test_torch_weights_without_the_training_stack_say_what_to_install(tmp_path) -> None:
    weights = tmp_path / "m.pt"
    weights.write_bytes(b"not read")
    code = (
        f"{BLOCK}\nfrom slimseg.deploy.predictor import Predictor\n"
        f"from slimseg.errors import SlimsegError\n"
        f"try:\n    Predictor.from_path({str(weights)!r})\n"
        f"except SlimsegError as e:\n    print(e)\n"
    )
    done = _python(code)
    assert done.stdout.strip() == (
        "loading .pt weights needs the training stack: pip install 'slimseg[train]'"
    ), done.stderr
