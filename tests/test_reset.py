"""The reset at the cost of what it resets: episodes drawn ahead in bulk and handed out, each
once, to the rows that reset. Its lots against the spec's distribution (an independent
rejection sampler as reference), independence, seeding, snapshots, and the in-place writes
that leave every other row and every tensor handed out untouched."""

from __future__ import annotations

import math

import pytest
import torch
from scipy import stats
from tensordict import TensorDict

from tests.conftest import (
    ALL_AIDS,
    COMPILED_BUILDS,
    COMPILED_GROUP,
    COMPILED_N,
    random_actions,
)
from torchpark import AidsConfig, BrakeConfig, NearGoalStarts, ParkingEnv
from torchpark.sim.layout import start_pose_valid, uniform_poses


def reset_rows(env: ParkingEnv, rows: torch.Tensor) -> TensorDict:
    mask = torch.zeros(env.num_envs, 1, dtype=torch.bool, device=env.device)
    mask[rows] = True
    return env._reset(TensorDict({"_reset": mask}, batch_size=[env.num_envs],
                                 device=env.device))


def partial_reset_lots(seed: int, lots: int, share: float, occupancy: float = 0.5
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, ParkingEnv]:
    """``lots`` lots from partial resets of ``share`` of 512 rows (random rows each call):
    their goal slots, parked-car masks and start poses."""
    env = ParkingEnv(512, seed=seed)
    env.occupancy = occupancy
    env.reset()
    gen = torch.Generator().manual_seed(seed)
    goals, parked, poses = [], [], []
    count = max(1, round(share * env.num_envs))
    while sum(len(g) for g in goals) < lots:
        rows = torch.randperm(env.num_envs, generator=gen)[:count]
        reset_rows(env, rows)
        state = env.state
        goals.append(state.goal_slot[rows])
        parked.append(state.present[rows, :env.layout.num_slots] > 0)
        poses.append(state.pose[rows])
    return torch.cat(goals), torch.cat(parked), torch.cat(poses), env


def rejection_starts(env: ParkingEnv, count: int, seed: int) -> torch.Tensor:
    """The spec's start distribution by plain rejection, no cap and no pool: uniform over the
    lot and heading, kept when the vehicle overlaps no slot and touches no wall."""
    gen = torch.Generator().manual_seed(seed)
    found = []
    while sum(len(f) for f in found) < count:
        poses = uniform_poses(env.layout, (8 * count,), gen)
        found.append(poses[start_pose_valid(poses, env.layout.slots_and_walls,
                                            env.config.vehicle)])
    return torch.cat(found)[:count]


@pytest.mark.slow
@pytest.mark.parametrize("share", [0.003, 0.1])
def test_partial_resets_draw_the_specs_lots(share):
    """Rows reset two at a time (hand-outs that meet the end of the 512 episodes drawn
    ahead exactly) or 51 at a time (hand-outs across it): every lot handed out once, and
    the spec's distribution."""
    goals, parked, poses, env = partial_reset_lots(seed=4, lots=6_000, share=share)
    # Continuous start poses: two equal rows would be one lot handed out twice, across
    # many refills of the episodes drawn ahead.
    assert torch.unique(poses, dim=0).shape[0] == poses.shape[0]
    assert poses.shape[0] > 10 * env.num_envs
    slots = env.layout.num_slots
    # Goals uniform over the slots (chi-square), never occupied; exactly round(p (S-1)) cars.
    counts = torch.bincount(goals, minlength=slots).numpy()
    assert stats.chisquare(counts).pvalue > 1e-3
    assert not parked.gather(1, goals[:, None]).any()
    assert (parked.sum(1) == math.floor(0.5 * (slots - 1) + 0.5)).all()
    # Each non-goal slot holds a car with probability 19/37 (19 cars, 37 non-goal slots).
    free_goal = (torch.arange(slots)[None] != goals[:, None]).sum(0).double()
    expected = free_goal * 19 / 37
    observed = parked.sum(0).double()
    chi2 = (((observed - expected) ** 2) / (expected * (1 - 19 / 37))).sum().item()
    assert stats.chi2.sf(chi2, slots) > 1e-3
    # Start poses: the same distribution as plain rejection sampling (two-sample KS on x, y,
    # heading), and valid.
    reference = rejection_starts(env, len(poses), seed=5)
    for column in range(3):
        assert stats.ks_2samp(poses[:, column].numpy(),
                              reference[:, column].numpy()).pvalue > 1e-3, column
    assert start_pose_valid(poses, env.layout.slots_and_walls, env.config.vehicle).all()


def test_a_reset_draws_at_the_occupancy_set_after_episodes_were_drawn_ahead():
    env = ParkingEnv(64, seed=0)
    env.occupancy = 0.2
    env.reset()
    reset_rows(env, torch.tensor([3]))  # draws 64 episodes ahead at 0.2, hands out one
    env.occupancy = 0.9
    reset_rows(env, torch.tensor([5, 9]))
    cars = (env.state.present[:, :env.layout.num_slots] > 0).sum(1)
    assert cars[3] == round(0.2 * 37) and (cars[[5, 9]] == math.floor(0.9 * 37 + 0.5)).all()
    assert (env.state.occupancy[[5, 9]] == 0.9).all()


def test_reseeding_discards_the_episodes_drawn_ahead():
    env = ParkingEnv(32, seed=1)
    env.reset()
    reset_rows(env, torch.tensor([0, 1]))
    env.set_seed(7)
    again = env.reset()["observation"]
    assert torch.equal(again, ParkingEnv(32, seed=7).reset()["observation"])


def test_rows_reset_together_get_the_next_episodes_in_index_order():
    """A partial reset hands out the episodes drawn ahead in order: two envs of one seed,
    one resetting rows {2, 9} at once and the other 2 then 9, give the same lots."""
    a, b = ParkingEnv(16, seed=2), ParkingEnv(16, seed=2)
    a.reset(), b.reset()
    reset_rows(a, torch.tensor([2, 9]))
    reset_rows(b, torch.tensor([2]))
    reset_rows(b, torch.tensor([9]))
    for x, y in zip(a.state, b.state, strict=True):
        assert torch.equal(x, y)


def test_the_state_is_a_copy_and_tensors_handed_out_are_never_written():
    env = ParkingEnv(8, seed=0, aids=AidsConfig(brake=BrakeConfig()))
    td = env.reset()
    state, aid = env.state, env.aid_state
    kept_state, kept_aid = [t.clone() for t in state], [t.clone() for t in aid]
    kept_td = td.clone()
    state.pose.zero_()  # a copy: the env does not see it
    assert not torch.equal(env.state.pose, state.pose)
    step = env.step(td.clone().set("action", torch.zeros(8, 2)))
    kept_step = step.clone()
    reset_rows(env, torch.arange(8))
    assert (td == kept_td).all() and (step == kept_step).all()
    assert all(torch.equal(a, b) for a, b in zip(kept_aid, aid, strict=True))
    assert all(torch.equal(a, b) for a, b in zip(kept_state[1:], list(state)[1:], strict=True))


@pytest.mark.xdist_group(COMPILED_GROUP)
@pytest.mark.slow
@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "compiled"])
@pytest.mark.parametrize("config, aids", [COMPILED_BUILDS["paper"], ALL_AIDS],
                         ids=["paper", "aided"])
def test_no_two_state_tensors_share_memory(compiled, config, aids):
    """A reset writes the env's state tensors in place: no two of them (nor the episodes
    drawn ahead) may be one buffer, after resets or steps, eager or compiled."""
    env = ParkingEnv(COMPILED_N, seed=0, config=config, aids=aids, compile_step=compiled)
    td = env.reset()
    for a in random_actions(COMPILED_N, 6, 2):
        td = env.step_and_maybe_reset(td.set("action", a))[1]
        tensors = [*torch.utils._pytree.tree_leaves(env._rows),
                   *torch.utils._pytree.tree_leaves(env._resets._ahead)]
        pointers = [t.untyped_storage().data_ptr() for t in tensors]
        assert len(set(pointers)) == len(pointers)


def test_near_goal_starts_follow_a_new_success_threshold():
    """Near-goal starts are drawn clear of the success test: a new threshold discards the
    episodes drawn ahead, so no start meets the new test."""
    aids = AidsConfig(near_goal_starts=NearGoalStarts(probability=1.0, reach=0.3,
                                                      lateral=0.05, heading=0.05))
    env = ParkingEnv(256, seed=0, aids=aids)
    env.set_success_threshold(1e-6)
    env.reset()
    reset_rows(env, torch.tensor([0]))  # episodes drawn ahead against 1e-6
    env.set_success_threshold(0.05)
    td = reset_rows(env, torch.arange(1, 256))
    assert not (td["cost"][1:, 0] < 0.05).any()


def test_a_snapshot_without_its_episodes_drawn_ahead_is_refused():
    """Every snapshot holds the episodes drawn ahead and how many are handed out: one
    without them (or handing out more than N) is refused by name, not continued otherwise."""
    env = ParkingEnv(1, seed=5)
    env.reset()
    saved = env.snapshot()
    older = {k: v for k, v in saved.items() if not k.startswith("ahead")}
    with pytest.raises(ValueError, match=r"snapshot must hold exactly .*'ahead_used'"):
        env.restore(older)
    with pytest.raises(ValueError, match=r"snapshot\['ahead_used'\] must be an int"):
        env.restore({**saved, "ahead_used": 2})
