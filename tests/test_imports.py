"""The house rules, by import: the paper's simulator (torchpark.sim) imports nothing from the
aids, the pictures or the trainers, and ``import torchpark`` needs none of the extras."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import torchpark

PACKAGE = Path(torchpark.__file__).parent
SIM_MAY_NOT_IMPORT = ("torchpark.aids", "torchpark.media", "torchpark.env", "torchpark.gym_env",
                      "torchpark.curriculum", "torchpark.runner", "trainers")


def imported_modules(path: Path, root: Path = PACKAGE.parent) -> list[str]:
    """Every module an ``import`` or ``from ... import`` in the file names (absolute; relative
    imports resolved against the file's package under ``root``)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the file's package
                base = ".".join(path.relative_to(root).with_suffix("").parts[
                    :-node.level])
                names.append(f"{base}.{node.module}" if node.module else base)
            else:
                names.append(node.module)
    return names


SIM_FILES = [*sorted((PACKAGE / "sim").glob("*.py")), PACKAGE / "config.py"]


@pytest.mark.parametrize("path", SIM_FILES, ids=lambda p: p.name)
def test_the_simulator_imports_nothing_above_it(path):
    bad = offending(path)
    assert not bad, f"{path.name} imports {bad}"


def offending(path: Path, root: Path = PACKAGE.parent) -> list[str]:
    return [name for name in imported_modules(path, root) if name.startswith(SIM_MAY_NOT_IMPORT)]


def test_the_rule_catches_absolute_and_relative_offenders(tmp_path):
    fake = tmp_path / "torchpark" / "sim" / "fake.py"
    fake.parent.mkdir(parents=True)
    fake.write_text("import torch\nfrom torchpark.sim.world import World\n"
                    "from torchpark.aids.docking import take_over\n"
                    "from ..media import rendering\nimport trainers.utils\n")
    assert offending(fake, tmp_path) == ["torchpark.aids.docking", "torchpark.media",
                                         "trainers.utils"]


def test_importing_torchpark_loads_no_picture_or_training_library():
    code = ("import sys, torchpark\n"
            "heavy = [m for m in ('PIL', 'imageio', 'matplotlib', 'tensorboard', 'omegaconf', "
            "'torchpark.media.rendering', 'trainers') if m in sys.modules]\n"
            "print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"
