"""The notebooks are committed without outputs (pytest --nbmake runs them; outputs would go
stale), and each imports the project's code (torchpark, trainers, benchmarks) rather than
copying it."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_the_four_notebooks_exist():
    assert [p.name for p in NOTEBOOKS] == ["01_environment.ipynb", "02_training.ipynb",
                                           "03_evaluation.ipynb", "04_throughput.ipynb"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_stripped_and_uses_the_package(path):
    book = nbformat.read(path, as_version=4)
    code = [c for c in book.cells if c.cell_type == "code"]
    assert all(not c.outputs and c.execution_count is None for c in code), \
        f"{path.name} holds outputs: clear them before committing"
    source = "\n".join(c.source for c in code)
    assert any(f"from {package}" in source for package in ("torchpark", "trainers", "benchmarks"))
