"""The distiller pinned: a small seeded run of every part of it (all the student's features,
the binned steering, each teacher setting, the collision weights, the final approach, the
cosine fit) gives the labelled states and the checkpoints of the distiller before its
refactor into a config tree (``tests/data/distill_reference.pt``, written at 356f9e1 by its
flat ``DistillConfig`` with the same settings and a hybrid teacher checkpoint of the smoke
preset with the brake and the docking law).

Bit for bit on the CPUs the reference was written on (AMD, torch's AVX512 kernels);
elsewhere the weights still are (counts of the same draws) and the labels, inputs and
networks agree to float32 rounding (seen: 2.4e-6 under ``ATEN_CPU_CAPABILITY=default``; on an
Intel Xeon with the same AVX512 kernels, 1 ulp in 8 of iteration 0's 672 labels).
"""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from torch.utils._pytree import tree_flatten

from torchpark.aids.config import AidsConfig, BrakeConfig, DockingConfig, NearGoalStarts
from torchpark.config import ParkingConfig
from torchpark.experts import TeacherConfig
from trainers.config import AgentConfig, EnvConfig, ModelConfig, upgraded_config
from trainers.distill import distill
from trainers.distill.config import (
    COARSE_PLANNER,
    DaggerConfig,
    DistillConfig,
    StudentConfig,
    check,
)

REFERENCE = Path(__file__).parent / "data" / "distill_reference.pt"
REFERENCE_KERNELS = "AVX512"
REFERENCE_VENDOR = "AuthenticAMD"


def on_the_reference_cpu() -> bool:
    """Whether this CPU rounds as the reference's did: its vendor (``/proc/cpuinfo``) and
    torch's kernel set both the reference's."""
    cpuinfo = Path("/proc/cpuinfo")
    vendor = cpuinfo.exists() and f": {REFERENCE_VENDOR}" in cpuinfo.read_text()
    return vendor and torch.backends.cpu.get_cpu_capability() == REFERENCE_KERNELS

PINNED = DistillConfig(
    teacher=TeacherConfig(
        planner=replace(COARSE_PLANNER, lateral=0.4, heading=0.2, law_lateral=0.6,
                        law_heading=0.55, gear_hold=0.75, car_margin=0.2),
        docking=replace(DockingConfig(), settle=0.05, retry=1.0),
        brake=BrakeConfig(steer_clear=5), reverse_margin=0.5, handover=5),
    student=StudentConfig(
        env=EnvConfig(num_envs=4, task=ParkingConfig(max_steps=50)),
        agent=AgentConfig(aids=AidsConfig(observe_position=True,
                                          near_goal_starts=NearGoalStarts(probability=0.5)),
                          action_exponents=[3.0, 1.0], gear_head=True,
                          features=["goal", "clearance", "gear", "scan_memory", "slots",
                                    "position"], memory_scans=2),
        model=ModelConfig(hidden=[16, 16], steer_bins=5)),
    dagger=DaggerConfig(iterations=2, steps=12, epochs=2, dagger_epochs=1, yardstick=4,
                        approach=8, collision_weight=10.0, stall_weight=5.0, lr_decay=True),
    seed=3)


def assert_same(ours, theirs, exact: bool, what: str) -> None:
    leaves, spec = tree_flatten(ours)
    their_leaves, their_spec = tree_flatten(theirs)
    assert spec == their_spec, what
    for a, b in zip(leaves, their_leaves, strict=True):
        if not isinstance(a, torch.Tensor):
            assert a == b, what
        elif exact:
            assert torch.equal(a, b), what
        else:
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5, msg=what)


@pytest.mark.slow
def test_the_distiller_gives_the_labels_and_checkpoints_of_the_one_before_its_refactor(
        tmp_path):
    check(PINNED)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the reference's (a fit's sums depend on the thread count)
    try:
        distill(PINNED, tmp_path)
    finally:
        torch.set_num_threads(threads)
    reference = torch.load(REFERENCE, weights_only=True)
    exact = on_the_reference_cpu()
    for k, (inputs, labels, weights) in enumerate(reference["data"]):
        ours = torch.load(tmp_path / "dagger_data" / f"iteration_{k:03d}.pt",
                          weights_only=True)
        assert torch.equal(ours[2], weights)
        assert_same(ours[1], labels, exact, f"the labels of iteration {k}")
        assert_same(ours[0], inputs, exact, f"the inputs of iteration {k}")
    assert reference["data"][0][2].max() == 10.0  # a collision was weighted
    for name in ("checkpoint_final.pt", "checkpoint_best.pt"):
        ours = torch.load(tmp_path / name, weights_only=True)
        assert ours["config"] == upgraded_config(reference[name]["config"])
        assert ours["frames"] == reference[name]["frames"]
        for key in ("actor", "obs_norm"):
            assert_same(ours[key], reference[name][key], exact, f"{name}'s {key}")
    rows = [{k: v for k, v in r.items() if k != "wall_s"}
            for r in csv.DictReader((tmp_path / "dagger.csv").read_text().splitlines())]
    if exact:
        assert rows == reference["dagger"]
