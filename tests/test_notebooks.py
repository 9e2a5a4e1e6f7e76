"""The notebooks are committed with their outputs, from one run top to bottom at full size
(``jupyter nbconvert --to notebook --execute --inplace notebooks/NAME.ipynb``, from the
``[lab]`` extra), so that a reader sees the pictures and tables without running them;
pytest --nbmake runs them again at small sizes (notebooks/conftest.py) without writing them
back. Each imports the project's code (torchpark, trainers, benchmarks) rather than
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
def test_notebook_holds_one_full_run_and_uses_the_package(path):
    book = nbformat.read(path, as_version=4)
    code = [c for c in book.cells if c.cell_type == "code"]
    counts = [c.execution_count for c in code]
    assert counts == list(range(1, len(code) + 1)), \
        f"{path.name}: run it top to bottom in a fresh kernel before committing ({counts})"
    errors = [o for c in code for o in c.outputs if o.output_type == "error"]
    assert not errors, f"{path.name} holds an error: {errors[0].get('ename')}"
    assert any(c.outputs for c in code), f"{path.name} holds no output"
    source = "\n".join(c.source for c in code)
    assert any(f"from {package}" in source for package in ("torchpark", "trainers", "benchmarks"))
