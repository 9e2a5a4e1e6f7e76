"""The benchmark's minimal kernel (benchmarks/kernel.py) computes the env's step: bit for bit
eager; compiled, the benchmark checks it against the eager kernel before timing it. The
floor the step is timed against is the same task."""

from __future__ import annotations

from functools import partial

import pytest
import torch
from tensordict import TensorDict

from benchmarks.kernel import KernelState, columns, kernel_step, lidar_env_inner
from benchmarks.throughput import check_compiled_kernel
from tests.conftest import random_actions
from torchpark import ParkingConfig, ParkingEnv
from torchpark.sim.lidar import lidar_scan


def assert_steps_alike(env: ParkingEnv, step) -> None:
    """30 random steps of ``env``'s step function and of the kernel ``step`` from its state:
    every output equal, ending rows among them."""
    sim = env.state
    state = KernelState(sim.pose, sim.goal, sim.steps, sim.present.t().contiguous())
    ended = 0
    for action in random_actions(env.num_envs, 30, 7):
        out = env._step(TensorDict(action=action, batch_size=[env.num_envs]))  # no reset
        state, observation, reward, terminated, truncated, cost = step(state, action)
        assert torch.equal(state.pose, env.state.pose)
        assert torch.equal(state.steps, env.state.steps)
        for ours, theirs in ((observation, out["observation"]), (reward, out["reward"][:, 0]),
                             (cost, out["cost"][:, 0]), (terminated, out["terminated"][:, 0]),
                             (truncated, out["truncated"][:, 0])):
            assert torch.equal(ours, theirs)
        ended += int(out["done"].sum())
    assert ended > 0  # collisions and timeouts were compared, not only running steps


@pytest.mark.parametrize("occupancy", [0.0, 0.5, 0.9])
def test_the_kernel_steps_as_the_env_does(occupancy):
    config = ParkingConfig(max_steps=20)  # episodes are truncated too
    env = ParkingEnv(256, seed=4, config=config)
    env.occupancy = occupancy
    env.reset()
    assert_steps_alike(env, partial(kernel_step, boxes=columns(env.world.obstacles),
                                    world=env.world, cfg=config))


def test_the_benchmark_times_no_compiled_kernel_that_computes_another_step():
    """benchmarks.throughput checks the compiled kernel against the eager one before timing
    it (compiling the kernel here cost 150 s: the check runs where the kernel is compiled);
    here the check itself: the eager kernel passes, one whose reward is off by 1e-3 not."""
    config = ParkingConfig(max_steps=20)
    env = ParkingEnv(16, seed=5, config=config)
    env.reset()
    sim = env.state
    state = KernelState(sim.pose, sim.goal, sim.steps, sim.present.t().contiguous())
    step = partial(kernel_step, boxes=columns(env.world.obstacles), world=env.world, cfg=config)
    actions = random_actions(16, 30, 7)
    check_compiled_kernel(step, step, state, actions)

    def off(state, action):
        new, observation, reward, *flags = step(state, action)
        return new, observation, reward + 1e-3, *flags

    with pytest.raises(RuntimeError, match="the compiled kernel's reward is not the eager"):
        check_compiled_kernel(off, step, state, actions)


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
