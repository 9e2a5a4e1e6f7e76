"""The batched env against the independent numpy reference, step by step, whole episodes.

Before each step the reference takes the env's pose (float32 values, exactly): both then apply
the same step map, and any difference is the step's, not float32 drift accumulated over
hundreds of steps (a 1e-6 rad heading drift moves a grazing LIDAR hit at 18 m by millimetres).
The pose each step produces is compared too, so the dynamics are checked every step."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchpark import ParkingConfig, ParkingEnv

from .reference import ReferenceConfig, ReferenceParkingEnv
from .test_env import place

N, STEPS, MAX_STEPS = 24, 200, 60
STILL = [0, 1, 2]  # stand still: truncation at MAX_STEPS
PARKERS = [3, 4, 5]  # teleported onto the goal now and then: success


def policy(step: int, gen: torch.Generator) -> torch.Tensor:
    """Sticky random driving (crashes into cars and walls), a few standing envs."""
    action = (torch.rand(N, 2, generator=gen) * 2 - 1) * torch.tensor([5.0, 0.785])
    action[:, 0] = action[:, 0].sign() * 3.0 + action[:, 0] * 0.4  # mostly 2-5 m/s
    action[STILL] = 0.0
    action[PARKERS] = 0.0 if step % 15 == 14 else action[PARKERS]
    return action


@pytest.mark.parametrize("occupancy, seed", [(0.9, 0), (0.4, 1)])
def test_batched_env_matches_reference_in_lockstep(occupancy, seed):
    env = ParkingEnv(N, seed=seed, config=ParkingConfig(max_steps=MAX_STEPS))
    env.occupancy = occupancy
    td = env.reset()
    refs = [ReferenceParkingEnv.from_batched(env, i) for i in range(N)]
    for i, ref in enumerate(refs):
        np.testing.assert_allclose(td["observation"][i].numpy(), ref.observation(), atol=1e-4)
    gen = torch.Generator().manual_seed(seed)
    seen = {"collision": 0, "success": 0, "truncated": 0}
    for step in range(STEPS):
        if step % 15 == 14:  # park the parkers exactly on their goal; they stand still next
            place(env, env.state.goal[PARKERS], PARKERS)
            for i in PARKERS:
                refs[i] = ReferenceParkingEnv.from_batched(env, i)
        action = policy(step, gen)
        pose_before = env.state.pose.double().clone()
        out, td = env.step_and_maybe_reset(td.set("action", action))
        nxt = out["next"]
        for i, ref in enumerate(refs):
            ref.x, ref.y, ref.psi = (float(v) for v in pose_before[i])
            expected = ref.step(action[i].double().numpy())
            if not nxt["done"][i]:  # done rows hold their next lot already
                x, y, psi = env.state.pose[i].double().tolist()
                np.testing.assert_allclose([x, y, np.cos(psi), np.sin(psi)],
                                           [ref.x, ref.y, np.cos(ref.psi), np.sin(ref.psi)],
                                           atol=1e-5)
            np.testing.assert_allclose(nxt["observation"][i].numpy(), expected["observation"],
                                       atol=1e-4, err_msg=f"step {step}, env {i}")
            assert nxt["reward"][i].item() == pytest.approx(expected["reward"], abs=1e-4)
            for key in ("terminated", "truncated", "success", "collision"):
                assert bool(nxt[key][i]) == expected[key], (key, step, i)
                seen[key] = seen.get(key, 0) + int(expected[key])
        for i in torch.nonzero(nxt["done"][:, 0]).flatten().tolist():
            refs[i] = ReferenceParkingEnv.from_batched(env, i)  # the env's new lot
            np.testing.assert_allclose(td["observation"][i].numpy(), refs[i].observation(),
                                       atol=1e-4)
    # The run covered every way an episode ends.
    assert seen["collision"] > 20 and seen["success"] >= 3 and seen["truncated"] >= 3, seen


def test_reference_accepts_torch_free_input():
    """The reference needs only arrays: one box, a goal and a pose."""
    ref = ReferenceParkingEnv(np.array([[10.0, 0.0, 0.0, 1.0, 1.0]]), np.array([0.0, 0.0, 0.0]),
                              np.array([0.0, 0.0, 0.0]), cfg=ReferenceConfig())
    out = ref.step([5.0, 0.0])
    assert out["observation"][7] == pytest.approx((10 - 1 - 2.5) / 20)  # ray 0 from box centre
    assert not out["collision"]
