"""The core install is the runtime: ``slimseg.Masker``, ``slimseg --help`` and the runtime's
commands (``info``, ``dynamic`` and ``predict`` on an ONNX model) import no module of the
``train`` extra; a command that needs it, missing, says so in one line and exits 2 (checked in
fresh interpreters, the train stack made unimportable)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from slimseg.cli.commands import COMMANDS
from slimseg.data.synth import generate
from slimseg.data.synth.categories import MOBILITY, NAMES
from slimseg.utils.extras import TRAIN_MODULES
from slimseg.utils.install_state import CORE, EXTRA_USES, ExtraState, requirements

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


@pytest.mark.parametrize("command", ["dynamic", "predict", "slam-eval", "slam", "info"])
def test_runtime_commands_parse_without_the_training_stack(command) -> None:
    done = _python(f"{BLOCK}\nfrom slimseg.cli.main import main\nmain(['{command}', '--help'])")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: slimseg {command}")


@pytest.mark.parametrize("command", ["train", "val", "export"])
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


def test_info_says_what_is_installed_without_the_training_stack() -> None:
    code = "from slimseg.cli.main import main\nassert main(['info']) == 0"
    done = _python(f"{BLOCK}\n{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("slimseg ") and lines[1].startswith("core: numpy ")
    table = lines[lines.index("extras (pip install 'slimseg[NAME]' adds one):") + 1 :]
    assert table[0].split() == ["extra", "state", "enables"]
    assert [ln.split()[0] for ln in table[2 : 2 + len(EXTRA_USES)]] == list(EXTRA_USES)
    assert lines[-2] == (
        "model size and cost (--model): the model report needs the training stack: "
        "pip install 'slimseg[train]'"
    )
    assert not {m.split(".")[0] for m in json.loads(lines[-1])} & set(HEAVY)


def test_info_model_without_the_training_stack_says_what_to_install() -> None:
    run = (
        "import sys\nfrom slimseg.cli.main import main\nsys.exit(main(['info', '--model', 'all']))"
    )
    done = _python(f"{BLOCK}\n{run}")
    assert done.returncode == 2
    assert done.stderr == (
        "slimseg info: error: the model report (--model) needs the training stack: "
        "pip install 'slimseg[train]'\n"
    )


def test_the_extras_listed_are_pyprojects() -> None:
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    reqs = requirements()
    assert reqs[CORE][:3] == ["numpy", "pyyaml", "opencv-python-headless"]
    assert reqs["train"][0] == "torch" and "rosbags" in reqs["ros"]
    assert set(EXTRA_USES) == set(project["optional-dependencies"]) - {"dev"}
    assert ExtraState("ros", "rosbags", {"protobuf": "5"}, ["rosbags"]).describe() == (
        "not installed"
    )
    assert ExtraState("ros", "rosbags", {"rosbags": "1"}, ["mcap"]).describe() == "missing mcap"
    assert ExtraState("ray", "ray", {"ray": "2"}, []).describe() == "installed"


@pytest.fixture(scope="module")
def onnx_sequence(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 4-frame synthetic TUM folder and a random-init 64-px segmenter exported to ONNX."""
    from slimseg.deploy.onnx_export import export_onnx
    from slimseg.models.registry import build_model

    root = tmp_path_factory.mktemp("core")
    generate(root / "d", 0, 0, 64, 0, sequences=1, frames=4, seq_size=(96, 64), progress=False)
    model = build_model("yolov8n-seg", num_classes=len(NAMES)).eval()
    onnx = root / "m.onnx"
    export_onnx(model, onnx, (64, 64), list(NAMES), list(MOBILITY), simplify=False)
    return root / "d" / "sequences" / "seq_000", onnx


def test_dynamic_and_predict_run_without_the_training_stack(
    onnx_sequence: tuple[Path, Path], tmp_path: Path
) -> None:
    seq, onnx = onnx_sequence
    common = f"'--model', {str(onnx)!r}, '--threads', '1', '--quiet'"
    code = (
        "from slimseg.cli.main import main\n"
        f"assert main(['dynamic', {common}, '--sequence', {str(seq)!r}, "
        f"'--out', {str(tmp_path / 'dyn')!r}]) == 0\n"
        f"assert main(['predict', {common}, '--source', {str(seq / 'rgb')!r}, "
        f"'--out', {str(tmp_path / 'pred')!r}]) == 0\n"
    )
    done = _python(f"{BLOCK}\n{code}")
    assert done.returncode == 0, done.stderr
    assert len(list((tmp_path / "dyn" / "masks").glob("*.png"))) == 4
    assert len(list((tmp_path / "pred").glob("*_overlay.*"))) == 4
