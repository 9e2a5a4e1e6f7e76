"""The reset inside the step's graph (``reset_in_step``, :mod:`torchpark.sim.ring`): its
hand-out against a plain reference of the host path's, whole rollouts equal to the host
path's, one compiled graph with no data-dependent shape, one host read per ``blocks_ahead``
steps, the deferred action check, snapshots, and the discards of episodes drawn ahead."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

import pytest
import torch
from tensordict import TensorDict
from torch.utils._python_dispatch import TorchDispatchMode
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs

from tests.conftest import BUSY, COMPILED_GROUP, COMPILED_N, RING_BUILD, random_actions
from torchpark import (
    AidsConfig,
    BrakeConfig,
    DockingConfig,
    NearGoalStarts,
    OccupancyCurriculum,
    ParkingConfig,
    ParkingEnv,
)
from torchpark.compiling import compiler_found
from torchpark.curriculum import PAPER_LEVELS
from torchpark.sim.ring import Counters, hand_out
from torchpark.transforms.sync_free import SyncFreeEnv

AIDED = AidsConfig(action_repeat=2, brake=BrakeConfig(), docking=DockingConfig(),
                   near_goal_starts=NearGoalStarts())


def reference_hand_out(masks: list[list[bool]]) -> list[list[tuple[int, int]]]:
    """The host path's order, one row at a time: (block, row of the block) for every ended
    row of every mask, blocks of N from block 1 on, a block's rest skipped when it does not
    hold every ended row."""
    n, block, used, given = len(masks[0]), 0, len(masks[0]), []
    for mask in masks:
        count = sum(mask)
        if count > n - used:
            block, used = block + 1, 0
        given.append([(block, used + k) for k in range(count)])
        used += count
    return given


@pytest.mark.parametrize("seed", range(20))
def test_hand_out_follows_the_host_paths_order(seed):
    gen = torch.Generator().manual_seed(seed)
    n, blocks = 1 + seed, 3
    share = torch.rand(60, generator=gen)  # from almost no row to every row per step
    masks = torch.rand(60, n, generator=gen) < share[:, None]
    counters = Counters(torch.tensor(0), torch.tensor(n))
    for mask, expected in zip(masks, reference_hand_out(masks.tolist()), strict=True):
        index, counters = hand_out(mask, counters, blocks)
        assert [divmod(int(i), n) for i in index[mask]] == [
            (block % blocks, row) for block, row in expected]
        assert ((index >= 0) & (index < blocks * n)).all()


def rollout(env: ParkingEnv, steps: int, seed: int) -> list[tuple[TensorDict, TensorDict]]:
    """``steps`` of ``step_and_maybe_reset`` with random actions: (td, td_) of each."""
    td, pairs = env.reset(), []
    for action in random_actions(env.num_envs, steps, seed).to(env.device):
        td, td_ = env.step_and_maybe_reset(td.set("action", action))
        pairs.append((td.clone(), td_.clone()))
        td = td_
    return pairs


def assert_same_rollout(ours: list, theirs: list) -> None:
    for step, ((a, a_), (b, b_)) in enumerate(zip(ours, theirs, strict=True)):
        for x, y in ((a, b), (a_, b_)):
            assert set(x.keys(True, True)) == set(y.keys(True, True)), step
            for key in x.keys(True, True):
                torch.testing.assert_close(x[key], y[key], rtol=0, atol=0, equal_nan=True,
                                           msg=f"step {step}, {key}")


@pytest.mark.slow
@pytest.mark.parametrize("aids", [None, AIDED], ids=["paper", "aided"])
@pytest.mark.parametrize("blocks_ahead", [1, 4])
def test_the_rollout_is_the_host_paths(aids, blocks_ahead):
    """Every key of td and td_ (ended rows' last observations, the new episodes, the padded
    action) at every step, bit for bit, through many ends and blocks."""
    host = ParkingEnv(48, seed=3, config=BUSY, aids=aids, reset_in_step=False)
    ring = ParkingEnv(48, seed=3, config=BUSY, aids=aids, reset_in_step=True,
                      blocks_ahead=blocks_ahead)
    theirs, ours = rollout(host, 60, seed=1), rollout(ring, 60, seed=1)
    assert sum(int(td["next", "done"].sum()) for td, _ in theirs) > 6 * 48  # many ends
    assert int(ring._resets._counters.block) > 2 * ring._resets.ring_blocks  # the ring went round
    assert_same_rollout(ours, theirs)


def rollout_changed(env: ParkingEnv, steps: int, seed: int, change: Callable[[ParkingEnv], None],
                    at: int, nan_rows: tuple[int, ...] = ()) -> list:
    """:func:`rollout` with ``change(env)`` before step ``at`` (what a curriculum does
    between two steps) and NaN actions in ``nan_rows`` at every third step."""
    td, pairs = env.reset(), []
    for k, action in enumerate(random_actions(env.num_envs, steps, seed)):
        if k == at:
            change(env)
        if k % 3 == 0:
            action[list(nan_rows)] = float("nan")
        td, td_ = env.step_and_maybe_reset(td.set("action", action))
        pairs.append((td.clone(), td_.clone()))
        td = td_
    return pairs


def _curriculum(env: ParkingEnv) -> None:
    env.occupancy = 0.6
    env.set_success_threshold(1e-3)  # with near-goal starts, a discard too


@pytest.mark.parametrize("aids", [None, AIDED], ids=["paper", "aided"])
def test_a_curriculum_mid_run_keeps_the_host_paths_rollout(aids):
    """The occupancy (and the threshold) changed between two steps, as OccupancyCurriculum
    does: both paths discard what they drew ahead and draw the same lots next; NaN actions
    (validate_actions=False) leave their rows standing on both."""
    envs = [ParkingEnv(40, seed=5, config=BUSY, aids=aids, reset_in_step=ring, blocks_ahead=3,
                       validate_actions=False) for ring in (False, True)]
    theirs, ours = (rollout_changed(env, 40, 2, _curriculum, at=17, nan_rows=(3, 7))
                    for env in envs)
    assert_same_rollout(ours, theirs)
    assert envs[1].occupancy == 0.6 and torch.isfinite(envs[1].state.pose).all()
    assert (envs[0].state.occupancy[envs[0].state.steps < 3] == 0.6).all()  # new lots at 0.6


@pytest.mark.parametrize("wrapper", [TransformedEnv, SyncFreeEnv], ids=["torchrl", "sync-free"])
def test_the_curriculum_transform_keeps_the_host_paths_rollout(wrapper):
    """OccupancyCurriculum raises the level at the step whose frames reach it: the rows the
    ring resets inside that step draw the new level's lots, as the host path's reset after
    the step does (the transform sets the level before each step). Through torchrl's
    generic step-and-reset and through SyncFreeEnv's, which resets inside the step."""
    envs = [wrapper(ParkingEnv(16, seed=3, config=BUSY, reset_in_step=ring, blocks_ahead=3),
                    OccupancyCurriculum(frames_per_level=16 * 25)) for ring in (False, True)]
    theirs, ours = (rollout(env, 80, seed=1) for env in envs)
    assert_same_rollout(ours, theirs)
    assert [env.base_env.occupancy for env in envs] == [PAPER_LEVELS[3]] * 2


def _set_some_rows(env: ParkingEnv) -> None:
    """Every third row put on its goal (their episodes end soon, and reset)."""
    state = env.state
    env.set_state(state._replace(pose=state.goal.clone()),
                  torch.arange(env.num_envs, device=env.device) % 3 == 0)


def _rewind(env: ParkingEnv) -> None:
    """A snapshot, then a new occupancy and a full reset, then the snapshot restored."""
    saved = env.snapshot()
    env.occupancy = 0.3
    env.reset()
    env.restore(saved)


SETTERS = {"occupancy": lambda env: setattr(env, "occupancy", 0.6),
           "success_threshold": lambda env: env.set_success_threshold(1e-3),
           "set_state": _set_some_rows, "restore": _rewind,
           "randomize_step_counts": lambda env: env.randomize_step_counts()}


@pytest.mark.parametrize("aids", [None, AIDED], ids=["paper", "aided"])
@pytest.mark.parametrize("at", [0, 17], ids=["after-the-first-reset", "mid-run"])
@pytest.mark.parametrize("setter", sorted(SETTERS))
def test_both_engines_keep_one_rollout_under_each_setter(setter, at, aids):
    """Each documented setter, right after the first reset (the ring has drawn every block
    ahead) or between two steps: the host path and the ring give the same rollout, bit for
    bit; a restore of a snapshot taken just before rewinds both as if nothing happened."""
    envs = [ParkingEnv(24, seed=5, config=BUSY, aids=aids, reset_in_step=ring, blocks_ahead=3)
            for ring in (False, True)]
    theirs, ours = (rollout_changed(env, 40, 2, SETTERS[setter], at=at) for env in envs)
    assert sum(int(td["next", "done"].sum()) for td, _ in theirs) > 24  # resets after it
    assert_same_rollout(ours, theirs)
    if setter == "restore":
        plain = ParkingEnv(24, seed=5, config=BUSY, aids=aids, reset_in_step=False)
        assert_same_rollout(ours, rollout(plain, 40, seed=2))


def test_both_engines_keep_one_sequence_of_partial_resets_under_the_setters():
    """Between partial resets (no step at all), each setter in turn: the same episodes."""
    envs = [ParkingEnv(16, seed=9, config=BUSY, reset_in_step=ring, blocks_ahead=2)
            for ring in (False, True)]
    gen = torch.Generator().manual_seed(1)
    for env in envs:
        env.reset()
    for name in sorted(SETTERS) * 2:
        mask = torch.rand(16, 1, generator=gen) < 0.5
        outputs = []
        for env in envs:
            SETTERS[name](env)
            outputs.append(env.reset(TensorDict({"_reset": mask}, batch_size=[16])))
        for key in outputs[0].keys(True, True):
            assert torch.equal(outputs[0][key], outputs[1][key]), (name, key)
        assert torch.equal(envs[0].state.steps, envs[1].state.steps), name


def test_a_partial_reset_is_the_host_paths():
    host = ParkingEnv(32, seed=8, config=BUSY, reset_in_step=False)
    ring = ParkingEnv(32, seed=8, config=BUSY, reset_in_step=True, blocks_ahead=2)
    gen = torch.Generator().manual_seed(0)
    for env in (host, ring):
        env.reset()
    for _ in range(12):
        mask = torch.rand(32, 1, generator=gen) < 0.4
        a, b = (env.reset(TensorDict({"_reset": mask}, batch_size=[32])) for env in (host, ring))
        for key in a.keys(True, True):
            assert torch.equal(a[key], b[key]), key


@pytest.mark.xdist_group(COMPILED_GROUP)
@pytest.mark.slow
@pytest.mark.skipif(not compiler_found(), reason="torch.compile needs a C++ compiler")
def test_one_graph_from_action_to_reset_compiles_without_dynamic_shapes():
    """The step and the reset of its ended rows compile as one graph (fullgraph=True) with no
    data-dependent shape allowed, and give the host path's compiled rollout."""
    config = torch._dynamo.config
    with config.patch(capture_dynamic_output_shape_ops=False, capture_scalar_outputs=False):
        torch._dynamo.reset()
        ring = ParkingEnv(COMPILED_N, seed=2, compile_step=True, **RING_BUILD)
        ours = rollout(ring, 40, seed=4)
    host = ParkingEnv(COMPILED_N, seed=2, config=BUSY, reset_in_step=False, compile_step=True)
    assert_same_rollout(ours, rollout(host, 40, seed=4))


class HostReads(TorchDispatchMode):
    """Counts the ops that read a tensor's values back to the host (on CUDA each is a
    synchronisation): scalar reads, ``nonzero``, ``equal``; ``Tensor.tolist`` is counted by
    the test (it does not pass through the dispatcher on a CPU)."""

    READS = ("aten._local_scalar_dense", "aten.nonzero", "aten.equal", "aten.is_nonzero")

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if str(func.overloadpacket) in self.READS:
            self.count += 1
        return func(*args, **(kwargs or {}))


@contextlib.contextmanager
def reads_counted(monkeypatch) -> Iterator[Callable[[], int]]:
    """The host reads made inside the block (:class:`HostReads` plus ``Tensor.tolist``);
    yields a function that returns their count so far."""
    tolist = torch.Tensor.tolist
    calls = []

    def counted(self):
        calls.append(1)
        return tolist(self)

    with monkeypatch.context() as patched, HostReads() as reads:
        patched.setattr(torch.Tensor, "tolist", counted)
        yield lambda: reads.count + len(calls)


def host_reads(env: ParkingEnv, steps: int, monkeypatch) -> int:
    td = env.reset()
    actions = random_actions(env.num_envs, steps, 0)
    with reads_counted(monkeypatch) as count:
        for action in actions:
            td = env.step_and_maybe_reset(td.set("action", action))[1]
        return count()


@pytest.mark.slow
def test_the_host_reads_back_once_every_blocks_ahead_steps(monkeypatch):
    steps = 48
    ring = ParkingEnv(32, seed=1, config=BUSY, reset_in_step=True, blocks_ahead=8)
    assert host_reads(ring, steps, monkeypatch) <= steps // 8 + 1
    host = ParkingEnv(32, seed=1, config=BUSY, reset_in_step=False)
    assert host_reads(host, steps, monkeypatch) >= steps  # the counter sees the host path's


def test_a_non_finite_action_stops_its_row_and_raises_at_the_next_read():
    env = ParkingEnv(4, seed=0, reset_in_step=True, blocks_ahead=3)
    td = env.reset()
    still = env.state
    action = torch.full((4, 2), 0.5)
    action[2, 0] = float("nan")
    td, td_ = env.step_and_maybe_reset(td.set("action", action))
    moved = env.state
    assert torch.equal(moved.pose[2], still.pose[2]) and int(moved.steps[2]) == 1
    assert not torch.equal(moved.pose[0], still.pose[0])
    with pytest.raises(ValueError, match="action must be finite"):
        for _ in range(3):
            td_ = env.step_and_maybe_reset(td_.set("action", torch.zeros(4, 2)))[1]
    # A step alone: the same, the error at a later reset's read of the counters.
    env = ParkingEnv(4, seed=0, reset_in_step=True, blocks_ahead=3)
    env.reset()
    env.step(TensorDict({"action": action}, batch_size=[4]))
    assert torch.equal(env.state.pose[2], still.pose[2])
    with pytest.raises(ValueError, match="action must be finite"):
        for _ in range(3):
            env.reset()
    # Not validated: no error, the row still stands still.
    quiet = ParkingEnv(4, seed=0, reset_in_step=True, blocks_ahead=1, validate_actions=False)
    td = quiet.reset()
    for _ in range(4):
        td = quiet.step_and_maybe_reset(td.set("action", action))[1]
    assert torch.equal(quiet.state.pose[2], still.pose[2])


def test_a_snapshot_continues_exactly_and_the_other_path_refuses_it():
    env = ParkingEnv(24, seed=6, config=BUSY, reset_in_step=True, blocks_ahead=2)
    td = env.reset()
    for action in random_actions(24, 9, 1):
        td = env.step_and_maybe_reset(td.set("action", action))[1]
    saved = env.snapshot()
    again = ParkingEnv(24, seed=0, config=BUSY, reset_in_step=True, blocks_ahead=2)
    again.restore(saved)
    for action in random_actions(24, 15, 2):
        a, a_ = env.step_and_maybe_reset(td.clone().set("action", action))
        b, b_ = again.step_and_maybe_reset(td.clone().set("action", action))
        assert_same_rollout([(b, b_)], [(a, a_)])
        td = a_
    host = ParkingEnv(24, seed=0, config=BUSY, reset_in_step=False)
    with pytest.raises(ValueError, match=r"built otherwise: reset_in_step=True in the snapshot"):
        host.restore(saved)
    other = ParkingEnv(24, seed=0, config=BUSY, reset_in_step=True, blocks_ahead=3)
    with pytest.raises(ValueError, match=r"built otherwise: ring_blocks=3 in the snapshot"):
        other.restore(saved)
    # The occupancy changed after a restore: both discard alike (the ring's generator states
    # are in the snapshot).
    again.restore(env.snapshot())
    for each in (env, again):
        each.occupancy = 0.2
    for action in random_actions(24, 12, 3):
        a, a_ = env.step_and_maybe_reset(td.clone().set("action", action))
        b, b_ = again.step_and_maybe_reset(td.clone().set("action", action))
        assert_same_rollout([(b, b_)], [(a, a_)])
        td = a_
    bad = {**saved, "ring_counters": torch.tensor([5, 0, 0])}  # a block never drawn
    with pytest.raises(ValueError, match=r"snapshot\['ring_counters'\]"):
        again.restore(bad)


def test_lots_drawn_ahead_at_another_occupancy_are_discarded():
    env = ParkingEnv(64, seed=0, config=ParkingConfig(occupancy=0.0), reset_in_step=True,
                     blocks_ahead=4)
    env.reset()  # four blocks drawn ahead, empty lots
    env.occupancy = 1.0
    mask = torch.ones(64, 1, dtype=torch.bool)
    env.reset(TensorDict({"_reset": mask}, batch_size=[64]))
    slots = env.layout.num_slots
    assert (env.state.present[:, :slots].sum(1) == slots - 1).all()


@pytest.mark.parametrize("aids", [None, AIDED], ids=["paper", "aided"])
def test_the_spec_check_passes_and_no_two_tensors_share_memory(aids):
    env = ParkingEnv(8, seed=0, aids=aids, reset_in_step=True, blocks_ahead=2)
    check_env_specs(env)
    td = env.reset()
    for action in random_actions(8, 6, 2):
        td = env.step_and_maybe_reset(td.set("action", action))[1]
        tensors = [*torch.utils._pytree.tree_leaves(env._rows),
                   *torch.utils._pytree.tree_leaves(env._resets._ring)]
        pointers = [t.untyped_storage().data_ptr() for t in tensors]
        assert len(set(pointers)) == len(pointers)


def test_blocks_ahead_is_checked():
    for bad in (0, 257, 10**5, 10**9, 2.5):  # bounded before anything is drawn
        with pytest.raises(ValueError, match=r"blocks_ahead must be an int in \[1, 256\]"):
            ParkingEnv(2, reset_in_step=True, blocks_ahead=bad)
    with pytest.raises(TypeError, match="reset_in_step must be a bool, got 'yes'"):
        ParkingEnv(2, reset_in_step="yes")
