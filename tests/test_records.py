"""torchpark.sim.records.replace: a NamedTuple's ``_replace`` that torch.compile keeps (torch
2.11 compiled ``_replace`` into an empty tuple), and the rule that the compiled code uses it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import torch

import torchpark
from torchpark.sim.records import replace
from torchpark.sim.state import ParkingState

PACKAGE = Path(torchpark.__file__).parent
# The modules whose functions the env compiles: the paper's step and the aided one.
COMPILED = sorted([*(PACKAGE / "sim").glob("*.py"), *(PACKAGE / "aids").glob("*.py")])


def test_replace_changes_the_named_fields_and_keeps_the_others():
    state = ParkingState.zeros(3, 5, "cpu")
    pose = torch.ones(3, 3)
    new = replace(state, pose=pose, steps=state.steps + 1)
    assert type(new) is ParkingState
    assert new.pose is pose and torch.equal(new.steps, torch.ones(3, dtype=torch.int64))
    assert all(getattr(new, f) is getattr(state, f) for f in ParkingState._fields
               if f not in ("pose", "steps"))


def test_replace_refuses_a_field_the_record_lacks():
    with pytest.raises(ValueError, match="ParkingState has no field 'heading'"):
        replace(ParkingState.zeros(1, 1, "cpu"), heading=torch.zeros(1))


def test_replace_compiles_into_a_whole_record():
    def step(state: ParkingState) -> ParkingState:
        return replace(state, speed=state.speed + 1.0)

    state = ParkingState.zeros(4, 2, "cpu")
    out = torch.compile(step, fullgraph=True, backend="eager")(state)
    assert type(out) is ParkingState and len(out) == len(ParkingState._fields)
    assert torch.equal(out.speed, torch.ones(4))


@pytest.mark.parametrize("path", COMPILED, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_compiled_code_never_calls_namedtuple_replace(path):
    """``x._replace(...)`` in the step's modules compiled into a tuple of no fields on torch
    2.11 (the env's compiled step and reset failed there, on CPU and CUDA)."""
    calls = [node.lineno for node in ast.walk(ast.parse(path.read_text()))
             if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
             and node.func.attr == "_replace"]
    assert not calls, f"{path.name}: ._replace( at line(s) {calls}; use records.replace"
