"""The layer order (docs/architecture.md §8) is checked, and the check can fail."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from slimseg.engine.config import load_train_config
from slimseg.errors import ConfigError
from slimseg.models.specs import SpecError

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(tree: Path) -> subprocess.CompletedProcess:
    env = os.environ | {"PYTHONPATH": str(tree)}
    return subprocess.run(
        [str(LINT), "--no-cache"], cwd=tree, env=env, capture_output=True, text=True, timeout=120
    )


@pytest.fixture(scope="module")
def package_copy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if not LINT.is_file():
        pytest.skip("import-linter is not installed (pip install -e '.[dev]')")
    tree = tmp_path_factory.mktemp("layers")
    shutil.copytree(
        ROOT / "slimseg", tree / "slimseg", ignore=shutil.ignore_patterns("__pycache__")
    )
    shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    return tree


def test_the_package_keeps_its_layer_order(package_copy: Path) -> None:
    result = _lint(package_copy)
    assert result.returncode == 0, result.stdout + result.stderr
    linter = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    assert f"{len(linter['contracts'])} kept, 0 broken" in result.stdout


@pytest.mark.parametrize(
    ("module", "upward"),
    [
        ("ops/boxes.py", "slimseg.cli.main"),  # a pure op reaching for the CLI
        ("dynamic/pipeline.py", "slimseg.deploy.predictor"),  # the old dynamic → deploy cycle
        ("models/checkpoint.py", "slimseg.engine.train"),  # models knowing the trainer
        ("detections.py", "slimseg.ops.boxes"),  # the leaf importing anything of slimseg
        # the file circles of issue #59, each closed again (the contracts inside a package)
        ("ablate/ray_backend.py", "slimseg.ablate.driver"),
        ("data/frame_source.py", "slimseg.data.tum"),
        ("utils/outputs.py", "slimseg.utils.atomic"),
    ],
)
def test_an_upward_import_breaks_the_contract(package_copy: Path, module: str, upward: str) -> None:
    target = package_copy / "slimseg" / module
    original = target.read_text()
    try:
        target.write_text(original + f"\nimport {upward}  # noqa: E402\n")
        result = _lint(package_copy)
    finally:
        target.write_text(original)
    assert result.returncode != 0
    assert upward in result.stdout


def test_a_typo_in_a_train_recipe_is_a_config_error_not_a_spec_error(tmp_path: Path) -> None:
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text("epochs: 3\nlr0: 0.01\nwarmup_epohcs: 1\n")
    with pytest.raises(ConfigError, match=r"recipe\.yaml.*warmup_epohcs") as err:
        load_train_config(recipe)
    assert not isinstance(err.value, SpecError)
    assert "model spec" not in str(err.value)
