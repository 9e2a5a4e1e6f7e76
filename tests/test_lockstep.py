"""The batched env against the independent numpy reference, step by step, whole episodes, on
the device under test (``--device``); and the env on that device against the CPU.

Before each step the reference takes the env's pose (float32 values, exactly): both then apply
the same step map, and any difference is the step's, not float32 drift accumulated over
hundreds of steps (a 1e-6 rad heading drift moves a grazing LIDAR hit at 18 m by millimetres).
The pose each step produces is compared too, so the dynamics are checked every step.

The comparison is exact to float32 rounding (1e-4 on observations and rewards) wherever the
geometry is well-posed. It is ill-posed on slivers of the input, where a hair decides: a ray
passing within RAY_EPS of a box corner hits the corner or misses it (its reading jumps), a car
within CONTACT_EPS of touching a box touches it or not, a cost within COST_EPS of the
threshold succeeds or not. float32 on another CPU's kernels, or on a GPU, may decide those
differently from float64, and both are right to their precision. Only those readings are
excused, each time counted, and the counts asserted rare.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from torchpark import ParkingConfig, ParkingEnv
from torchpark.sim.observation import NAV_DIM
from torchpark.sim.state import ParkingState

from .reference import ReferenceConfig, ReferenceParkingEnv

N, STEPS, MAX_STEPS = 24, 200, 60
STILL = [0, 1, 2]  # stand still: truncation at MAX_STEPS
PARKERS = [3, 4, 5]  # teleported onto the goal now and then: success
RAY_EPS = 1e-4  # m, ~10x float32's error on a ray's origin and direction 20 m out
CONTACT_EPS = 1e-4  # m, likewise for a corner of the car's box
COST_EPS = 1e-5  # float32's error on C is ~1e-6 (poses ~30 m, weights 0.35)
FLAGS = ("terminated", "truncated", "success", "collision")


def policy(step: int, gen: torch.Generator) -> torch.Tensor:
    """Sticky random driving (crashes into cars and walls), a few standing envs."""
    action = (torch.rand(N, 2, generator=gen) * 2 - 1) * torch.tensor([5.0, 0.785])
    action[:, 0] = action[:, 0].sign() * 3.0 + action[:, 0] * 0.4  # mostly 2-5 m/s
    action[STILL] = 0.0
    action[PARKERS] = 0.0 if step % 15 == 14 else action[PARKERS]
    return action


def park(env: ParkingEnv, rows: list[int]) -> None:
    """Teleport ``rows`` exactly onto their goal pose (test helper)."""
    pose = env.state.pose.clone()
    pose[rows] = env.state.goal[rows]
    mask = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
    mask[rows] = True
    env.set_state(env.state._replace(pose=pose), mask)


@dataclass
class Excused:
    """How often an ill-posed reading was excused, out of how many compared."""

    rays: int = 0
    ray_readings: int = 0
    flags: int = 0
    flag_readings: int = 0

    def assert_rare(self) -> None:
        assert self.rays <= 1e-3 * self.ray_readings, self
        assert self.flags <= 5e-3 * self.flag_readings, self


def compare(observation: np.ndarray, ref: ReferenceParkingEnv, expected: np.ndarray,
            excused: Excused, where: str) -> None:
    """An observation (7 + n_rays,) against the reference's, rays near a corner excused."""
    grazing = ref.ray_margins() < RAY_EPS
    excused.rays += int(grazing.sum())
    excused.ray_readings += grazing.size
    well_posed = np.concatenate((np.ones(7, dtype=bool), ~grazing))
    np.testing.assert_allclose(observation[well_posed], expected[well_posed], atol=1e-4,
                               err_msg=where)


def flags_ill_posed(ref: ReferenceParkingEnv, excused: Excused) -> bool:
    """Whether the step's collision or success test is within a hair of flipping."""
    ill = (ref.contact_margin() < CONTACT_EPS
           or abs(ref.cost() - ref.cfg.success_threshold) < COST_EPS)
    excused.flags += int(ill)
    excused.flag_readings += 1
    return ill


@pytest.mark.slow
@pytest.mark.parametrize("occupancy, seed", [(0.9, 0), (0.4, 1)])
def test_batched_env_matches_reference_in_lockstep(occupancy, seed, device):
    env = ParkingEnv(N, seed=seed, config=ParkingConfig(max_steps=MAX_STEPS), device=device)
    env.occupancy = occupancy
    td = env.reset()
    excused = Excused()
    refs = [ReferenceParkingEnv.from_batched(env, i) for i in range(N)]
    for i, ref in enumerate(refs):
        compare(td["observation"][i].cpu().numpy(), ref, ref.observation(), excused, "reset")
    gen = torch.Generator().manual_seed(seed)
    seen = dict.fromkeys(FLAGS, 0)
    for step in range(STEPS):
        if step % 15 == 14:  # park the parkers exactly on their goal; they stand still next
            park(env, PARKERS)
            for i in PARKERS:
                refs[i] = ReferenceParkingEnv.from_batched(env, i)
        action = policy(step, gen)
        pose_before = env.state.pose.double().cpu().clone()
        out, td = env.step_and_maybe_reset(td.set("action", action.to(device)))
        nxt = out["next"].cpu()
        for i, ref in enumerate(refs):
            ref.x, ref.y, ref.psi = (float(v) for v in pose_before[i])
            expected = ref.step(action[i].double().numpy())
            where = f"step {step}, env {i}"
            if not nxt["done"][i]:  # done rows hold their next lot already
                x, y, psi = env.state.pose[i].double().tolist()
                np.testing.assert_allclose([x, y, np.cos(psi), np.sin(psi)],
                                           [ref.x, ref.y, np.cos(ref.psi), np.sin(ref.psi)],
                                           atol=1e-5, err_msg=where)
            compare(nxt["observation"][i].numpy(), ref, expected["observation"], excused, where)
            for key in FLAGS:
                seen[key] += int(expected[key])
            if flags_ill_posed(ref, excused):
                refs[i] = ReferenceParkingEnv.from_batched(env, i)  # follow the env's choice
                continue
            assert nxt["reward"][i].item() == pytest.approx(expected["reward"], abs=1e-4), where
            for key in FLAGS:
                assert bool(nxt[key][i]) == expected[key], (key, where)
        for i in torch.nonzero(nxt["done"][:, 0]).flatten().tolist():
            refs[i] = ReferenceParkingEnv.from_batched(env, i)  # the env's new lot
            compare(td["observation"][i].cpu().numpy(), refs[i], refs[i].observation(),
                    excused, f"reset after step {step}, env {i}")
    # The run covered every way an episode ends, and excused little.
    assert seen["collision"] > 20 and seen["success"] >= 3 and seen["truncated"] >= 3, seen
    excused.assert_rare()
    print(f"\n{device}, occupancy {occupancy}, seed {seed}: excused {excused}")


def copy_rows(source: ParkingEnv, target: ParkingEnv, rows: torch.Tensor) -> None:
    """Give ``target`` the state of ``source``'s ``rows`` (N,) bool (observed on the
    target's device)."""
    dev = target.device
    target.set_state(ParkingState(*(t.to(dev) for t in source.state)), rows.to(dev))


def test_device_matches_cpu_over_whole_episodes(device):
    """The same lots and actions on the CPU and on ``--device``: each env steps on its own
    from the reset to the episode's end (no re-synchronisation within an episode), through
    collisions, successes and truncations; flags agree exactly and observations and rewards
    to float32 rounding, but for the ill-posed readings (measured by the float64 reference
    at the CPU's state). The CPU's new lots are copied over at every reset."""
    if device.type == "cpu":
        pytest.skip("compares the CPU with --device; run with --device cuda")
    config = ParkingConfig(max_steps=MAX_STEPS)
    cpu = ParkingEnv(N, seed=3, config=config)
    other = ParkingEnv(N, seed=3, config=config, device=device, validate_actions=False)
    cpu.occupancy = other.occupancy = 0.6
    td_cpu, td_other = cpu.reset(), other.reset()
    copy_rows(cpu, other, torch.ones(N, dtype=torch.bool))
    excused = Excused()
    seen = dict.fromkeys(FLAGS, 0)
    gen = torch.Generator().manual_seed(3)
    largest = 0.0
    for step in range(STEPS):
        if step % 15 == 14:
            park(cpu, PARKERS)
            park(other, PARKERS)
        action = policy(step, gen)
        refs = [ReferenceParkingEnv.from_batched(cpu, i) for i in range(N)]
        out_cpu, td_cpu = cpu.step_and_maybe_reset(td_cpu.set("action", action))
        out, td_other = other.step_and_maybe_reset(td_other.set("action", action.to(device)))
        a, b = out_cpu["next"], out["next"].cpu()
        resync = a["done"][:, 0] | b["done"][:, 0]
        for i, ref in enumerate(refs):
            expected = ref.step(action[i].double().numpy())
            where = f"step {step}, env {i}"
            compare(b["observation"][i].numpy(), ref, a["observation"][i].numpy(), excused,
                    where)
            for key in FLAGS:
                seen[key] += int(a[key][i])
            if flags_ill_posed(ref, excused):
                resync[i] = True
                continue
            assert b["reward"][i].item() == pytest.approx(a["reward"][i].item(), abs=1e-4), where
            for key in FLAGS:
                assert bool(b[key][i]) == bool(a[key][i]) == expected[key], (key, where)
        nav = (a["observation"][:, :NAV_DIM] - b["observation"][:, :NAV_DIM]).abs().max()
        largest = max(largest, nav)
        copy_rows(cpu, other, resync)
    assert seen["collision"] > 20 and seen["success"] >= 3 and seen["truncated"] >= 3, seen
    excused.assert_rare()
    print(f"\n{device}: largest navigation difference {largest:.2e}; excused {excused}")


def test_reference_accepts_torch_free_input():
    """The reference needs only arrays: one box, a goal and a pose."""
    ref = ReferenceParkingEnv(np.array([[10.0, 0.0, 0.0, 1.0, 1.0]]), np.array([0.0, 0.0, 0.0]),
                              np.array([0.0, 0.0, 0.0]), cfg=ReferenceConfig())
    out = ref.step([5.0, 0.0])
    assert out["observation"][7] == pytest.approx((10 - 1 - 2.5) / 20)  # ray 0 from box centre
    assert not out["collision"]
    assert ref.contact_margin() == pytest.approx(4.0)  # box face at 9 m, car front at 5 m
