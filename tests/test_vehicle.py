"""The kinematic bicycle against its closed form, and the footprint box."""

from __future__ import annotations

import math

import pytest
import torch

from torchpark import VehicleConfig
from torchpark.sim.geometry import box_corners
from torchpark.sim.vehicle import bicycle_step, clamp_action, vehicle_boxes

CFG = VehicleConfig()


def roll(pose, v, delta, steps):
    pose = torch.as_tensor(pose, dtype=torch.float64)
    v, delta = torch.as_tensor(v, dtype=torch.float64), torch.as_tensor(delta, dtype=torch.float64)
    for _ in range(steps):
        pose = bicycle_step(pose, v, delta, CFG)
    return pose


@pytest.mark.parametrize("psi", [0.0, 0.7, -2.5, math.pi])
@pytest.mark.parametrize("v", [3.0, -1.5])
def test_straight_line(psi, v):
    end = roll([1.0, 2.0, psi], v, 0.0, 50)
    distance = v * CFG.dt * 50
    assert end[0].item() == pytest.approx(1.0 + distance * math.cos(psi), abs=1e-9)
    assert end[1].item() == pytest.approx(2.0 + distance * math.sin(psi), abs=1e-9)
    assert math.cos(end[2].item()) == pytest.approx(math.cos(psi), abs=1e-12)


@pytest.mark.parametrize("delta", [0.3, -0.785, 0.05])
@pytest.mark.parametrize("v", [2.0, -4.0])
def test_constant_curvature_arc(delta, v):
    """Explicit Euler keeps the heading exact: psi_k = psi_0 + k w dt with w = v tan(delta)/L,
    and positions are the sum of the chords: closed form by the geometric series."""
    steps, psi0 = 40, 0.4
    w = v * math.tan(delta) / CFG.wheelbase
    end = roll([0.0, 0.0, psi0], v, delta, steps)
    step = v * CFG.dt
    x = sum(step * math.cos(psi0 + k * w * CFG.dt) for k in range(steps))
    y = sum(step * math.sin(psi0 + k * w * CFG.dt) for k in range(steps))
    assert end[0].item() == pytest.approx(x, abs=1e-9)
    assert end[1].item() == pytest.approx(y, abs=1e-9)
    expected_psi = math.remainder(psi0 + steps * w * CFG.dt, 2 * math.pi)
    assert end[2].item() == pytest.approx(expected_psi, abs=1e-9)
    # and the arc converges to the circle of radius L / tan(delta) around the turn centre
    radius = CFG.wheelbase / math.tan(delta)
    centre = (-radius * math.sin(psi0), radius * math.cos(psi0))
    fine = roll([0.0, 0.0, psi0], v / 100, delta, steps * 100)  # dt -> dt/100 equivalent
    r = math.hypot(fine[0].item() - centre[0], fine[1].item() - centre[1])
    assert r == pytest.approx(abs(radius), rel=2e-3)


def test_clamp_action_limits():
    v, delta = clamp_action(torch.tensor([[9.0, -2.0], [-7.0, 0.1]]), CFG)
    assert v.tolist() == [5.0, -5.0]
    assert delta.tolist() == pytest.approx([-0.785, 0.1])


def test_footprint_spans_rear_overhang_to_front():
    box = vehicle_boxes(torch.tensor([0.0, 0.0, 0.0]), CFG)
    corners = box_corners(box)
    assert corners[:, 0].min().item() == pytest.approx(-0.5)
    assert corners[:, 0].max().item() == pytest.approx(4.5)
    assert corners[:, 1].abs().max().item() == pytest.approx(1.0)
