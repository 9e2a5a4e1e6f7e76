"""The house rules, by import: each room of torchpark imports nothing above it (the paper's
simulator, ``sim``, nothing but itself and the task's config; the aids composed into the step
nothing from the policy-side transforms, the experts, the pictures, the env or the
trainers; ...), and ``import torchpark`` needs none of the extras."""

from __future__ import annotations

import ast
import graphlib
import subprocess
import sys
from pathlib import Path

import pytest

import torchpark

PACKAGE = Path(torchpark.__file__).parent
# What is above the simulator: everything but itself and the task's config (and files).
ABOVE_SIM = ("torchpark.aids", "torchpark.transforms", "torchpark.experts", "torchpark.media",
             "torchpark.env", "torchpark.gym_env", "torchpark.curriculum", "torchpark.runner",
             "trainers")
ABOVE_AIDS = tuple(name for name in ABOVE_SIM if name != "torchpark.aids")
# room -> the modules its files may not import
RULES = {
    "sim": ABOVE_SIM,
    "aids": ABOVE_AIDS,
    "transforms": ("torchpark.aids", "torchpark.experts", "torchpark.media", "torchpark.env",
                   "torchpark.gym_env", "torchpark.runner", "trainers"),
    "experts": ("torchpark.transforms", "torchpark.media", "torchpark.gym_env",
                "torchpark.runner", "trainers"),
    "media": ("torchpark.aids", "torchpark.transforms", "torchpark.experts", "trainers"),
}


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


ROOMS = [(room, path) for room in RULES for path in sorted((PACKAGE / room).glob("*.py"))]
ROOMS.append(("sim", PACKAGE / "config.py"))  # the task's config is the simulator's


@pytest.mark.parametrize("room, path", ROOMS, ids=lambda x: x if isinstance(x, str) else x.name)
def test_each_room_imports_nothing_above_it(room, path):
    bad = offending(path, RULES[room])
    assert not bad, f"{room}/{path.name} imports {bad}"


def test_every_room_holds_modules():
    assert {room for room, _ in ROOMS} == set(RULES)
    assert all(any(r == room for r, _ in ROOMS[:-1]) for room in RULES)


def offending(path: Path, forbidden: tuple[str, ...], root: Path = PACKAGE.parent
              ) -> list[str]:
    return [name for name in imported_modules(path, root)
            if any(name == f or name.startswith(f + ".") for f in forbidden)]


def test_the_rule_catches_absolute_and_relative_offenders(tmp_path):
    fake = tmp_path / "torchpark" / "sim" / "fake.py"
    fake.parent.mkdir(parents=True)
    fake.write_text("import torch\nfrom torchpark.sim.world import World\n"
                    "from torchpark.aids.docking import take_over\n"
                    "from ..media import rendering\nimport trainers.utils\n")
    assert offending(fake, RULES["sim"], tmp_path) == ["torchpark.aids.docking",
                                                       "torchpark.media", "trainers.utils"]
    assert offending(fake, RULES["aids"], tmp_path) == ["torchpark.media", "trainers.utils"]


@pytest.mark.slow
def test_importing_torchpark_loads_no_picture_or_training_library():
    code = ("import sys, torchpark\n"
            "heavy = [m for m in ('PIL', 'imageio', 'matplotlib', 'tensorboard', 'omegaconf', "
            "'torchpark.media.rendering', 'trainers') if m in sys.modules]\n"
            "print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"


def import_graph(package: Path, root: Path) -> dict[str, set[str]]:
    """Module -> the package's modules it imports, anywhere in the file (inside functions and
    ``if TYPE_CHECKING:`` too); a package is its ``__init__``."""
    names = {}
    for path in package.rglob("*.py"):
        parts = path.relative_to(root).with_suffix("").parts
        names[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path

    def module_of(name: str) -> str | None:  # a name imported from a module is that module
        while name and name not in names:
            name = name.rpartition(".")[0]
        return name or None

    return {module: {found for name in imported_modules(path, root)
                     if (found := module_of(name)) not in (None, module)}
            for module, path in names.items()}


def test_no_module_imports_one_that_imports_it_back():
    graphlib.TopologicalSorter(import_graph(PACKAGE, PACKAGE.parent)).prepare()


def test_the_circle_check_catches_a_type_only_circle(tmp_path):
    sim = tmp_path / "torchpark" / "sim"
    sim.mkdir(parents=True)
    (sim / "step.py").write_text("from torchpark.sim.observation import observe\n")
    (sim / "observation.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                        "    from torchpark.sim.step import ParkingState\n")
    graph = import_graph(tmp_path / "torchpark", tmp_path)
    assert graph == {"torchpark.sim.step": {"torchpark.sim.observation"},
                     "torchpark.sim.observation": {"torchpark.sim.step"}}
    with pytest.raises(graphlib.CycleError):
        graphlib.TopologicalSorter(graph).prepare()


# torchrl's private names torchpark uses (torchpark/_compat.py); an override's own
# ``super().<name>(...)`` is the hook's contract, not a use.
TORCHRL_PRIVATE = ("_step_mdp", "_post_step_mdp_hooks", "_reset_env_preprocess", "_carrier",
                   "_maybe_stateful_init")


def private_uses(path: Path) -> list[str]:
    """The private torch / torchrl names a file reaches: imports of a private module
    (``torch._inductor``, ``torch.utils._pytree``), ``torch._x`` attribute chains, and
    :data:`TORCHRL_PRIVATE` attributes other than ``super().<name>``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import | ast.ImportFrom):
            modules = ([a.name for a in node.names] if isinstance(node, ast.Import)
                       else [node.module or ""])
            found += [m for m in modules if m.split(".")[0] in ("torch", "torchrl", "tensordict")
                      and any(part.startswith("_") for part in m.split("."))]
        elif isinstance(node, ast.Attribute):
            chain, value = [node.attr], node.value
            while isinstance(value, ast.Attribute):
                chain.append(value.attr)
                value = value.value
            if isinstance(value, ast.Name) and value.id == "torch" and any(
                    part.startswith("_") and not part.startswith("__") for part in chain):
                found.append(".".join(["torch", *reversed(chain)]))
            elif node.attr in TORCHRL_PRIVATE and not (
                    isinstance(node.value, ast.Call) and isinstance(node.value.func, ast.Name)
                    and node.value.func.id == "super"):
                found.append(node.attr)
    # torch._dynamo.config is walked as itself and as torch._dynamo: the longest chain only
    return sorted({f for f in found if not any(g.startswith(f + ".") for g in found)})


CODE = [path for folder in ("torchpark", "trainers", "benchmarks")
        for path in sorted((PACKAGE.parent / folder).rglob("*.py"))
        if path != PACKAGE / "_compat.py"]


@pytest.mark.parametrize("path", CODE, ids=lambda p: str(p.relative_to(PACKAGE.parent)))
def test_private_torch_and_torchrl_names_are_reached_through_compat_alone(path):
    assert not private_uses(path), f"use torchpark._compat for {private_uses(path)}"


def test_the_private_name_rule_catches_each_form(tmp_path):
    fake = tmp_path / "fake.py"
    fake.write_text("import torch\nfrom torch.utils._pytree import tree_map\n"
                    "import torch._inductor.config\nx = torch._dynamo.config\n"
                    "y = env._step_mdp(td)\nz = collector._carrier\n"
                    "def _maybe_stateful_init(self, d):\n    super()._maybe_stateful_init(d)\n"
                    "w = torch.compiler.reset()\n")
    assert private_uses(fake) == ["_carrier", "_step_mdp", "torch._dynamo.config",
                                  "torch._inductor.config", "torch.utils._pytree"]


AID_FIELDS = ("brake", "docking", "near_goal_starts", "observe_position")


def plumbing_faults(source: str, limit: int = 300) -> list[str]:
    """What keeps the class ``ParkingEnv`` in ``source`` from being plumbing: more than
    ``limit`` lines, more than two conditions on ``reset_in_step`` (its default and the
    engine it builds: the engines hold the rest), a condition on an aid's config."""
    cls = next(n for n in ast.parse(source).body
               if isinstance(n, ast.ClassDef) and n.name == "ParkingEnv")

    def names(node: ast.AST) -> set[str]:
        return {n.id if isinstance(n, ast.Name) else n.attr for n in ast.walk(node)
                if isinstance(n, (ast.Name, ast.Attribute))}

    tests = [names(n.test) for n in ast.walk(cls) if isinstance(n, (ast.If, ast.IfExp))]
    faults = [f"{cls.end_lineno - cls.lineno + 1} lines"] \
        if cls.end_lineno - cls.lineno + 1 > limit else []
    ring = sum("reset_in_step" in t for t in tests)
    faults += [f"{ring} conditions on reset_in_step"] if ring > 2 else []
    return faults + [f"a condition on {f}" for f in AID_FIELDS if any(f in t for t in tests)]


def test_the_env_class_is_plumbing():
    assert plumbing_faults((PACKAGE / "env.py").read_text()) == []


def test_the_plumbing_rule_catches_each_fault():
    branchy = ("class ParkingEnv:\n    def a(self):\n" + "        pass\n" * 3
               + "".join("        if self.reset_in_step:\n            pass\n" for _ in range(3))
               + "        x = 1 if self._agent.brake is not None else 2\n")
    assert plumbing_faults(branchy, limit=5) == [
        "12 lines", "3 conditions on reset_in_step", "a condition on brake"]
