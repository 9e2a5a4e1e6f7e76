"""The benchmark's minimal kernel (benchmarks/kernel.py) computes the env's step: bit for bit
eager; compiled, to the rounding of the compiled kernels' trigonometry, as the env's compiled
step differs from its eager one (tests/test_env.py). The floor the step is timed against is
the same task."""

from __future__ import annotations

from functools import partial

import pytest
import torch

from benchmarks.kernel import OPTIONS, KernelState, columns, kernel_step, lidar_env_inner
from tests.conftest import COMPILED_N, SHORT, random_actions
from torchpark import ParkingConfig, ParkingEnv
from torchpark.sim.lidar import lidar_scan


def assert_steps_alike(env: ParkingEnv, step, atol: float = 0.0) -> None:
    """30 random steps of ``env``'s step function and of the kernel ``step`` from its state:
    every output equal (the observation, reward and cost within ``atol``), ending rows among
    them."""
    aided = env._state
    sim = aided.sim
    state = KernelState(sim.pose, sim.goal, sim.steps, sim.present.t().contiguous())
    ended = 0
    for action in random_actions(env.num_envs, 30, 7):
        aided, out, _ = env._guarded_fn(aided, action, env._no_bad_action)  # what step runs
        state, observation, reward, terminated, truncated, cost = step(state, action)
        assert torch.equal(state.pose, aided.sim.pose)
        assert torch.equal(state.steps, aided.sim.steps)
        for ours, theirs in ((observation, out.observation), (reward, out.reward[:, 0]),
                             (cost, out.cost[:, 0])):
            assert torch.allclose(ours, theirs, rtol=0.0, atol=atol) if atol \
                else torch.equal(ours, theirs)
        assert torch.equal(terminated, out.terminated[:, 0])
        assert torch.equal(truncated, out.truncated[:, 0])
        ended += int(out.done.sum())
    assert ended > 0  # collisions and timeouts were compared, not only running steps


@pytest.mark.parametrize("occupancy", [0.0, 0.5, 0.9])
def test_the_kernel_steps_as_the_env_does(occupancy):
    config = ParkingConfig(max_steps=20)  # episodes are truncated too
    env = ParkingEnv(256, seed=4, config=config)
    env.occupancy = occupancy
    env.reset()
    assert_steps_alike(env, partial(kernel_step, boxes=columns(env.world.obstacles),
                                    world=env.world, cfg=config))


@pytest.mark.slow
def test_the_compiled_kernel_steps_as_the_compiled_env_does():
    env = ParkingEnv(COMPILED_N, seed=5, config=SHORT, compile_step=True)
    env.reset()
    step = torch.compile(partial(kernel_step, boxes=columns(env.world.obstacles),
                                 world=env.world, cfg=SHORT), fullgraph=True, options=OPTIONS)
    assert_steps_alike(env, step, atol=1e-5)


def test_the_kernels_lidar_is_the_envs_on_random_poses():
    env = ParkingEnv(2, seed=0)
    world, g = env.world, torch.Generator().manual_seed(5)
    n = 4096
    x, y = torch.rand(n, generator=g) * 50 - 2.5, torch.rand(n, generator=g) * 40 - 2.5
    psi = torch.rand(n, generator=g) * 6.3 - 3.15
    present = (torch.rand(n, world.obstacles.cx.shape[0], generator=g) < 0.5).float()
    c, s = torch.cos(psi), torch.sin(psi)
    ours = lidar_env_inner(x, y, c, s, world.rotation, columns(world.obstacles),
                           present.t().contiguous(), 16, 20.0)
    assert torch.equal(ours, lidar_scan(x, y, c, s, world.rotation, world.obstacles, present,
                                        16, 20.0))
