"""ParkingEnv's plumbing: specs, the reset's mask, seeding, dispatch to the paper's or the
aided step (compiled or not), setting a state, and input checks."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs import EnvBase, InitTracker, TransformedEnv
from torchrl.envs.utils import check_env_specs

from tests.conftest import (
    COMPILED_BUILDS,
    COMPILED_GROUP,
    COMPILED_N,
    RING_BUILD,
    act,
    random_actions,
)
from tests.test_ring import assert_same_rollout, rollout
from torchpark import (
    AidsConfig,
    BrakeConfig,
    DockingConfig,
    LidarConfig,
    LotConfig,
    NearGoalStarts,
    ParkingConfig,
    ParkingEnv,
    RewardConfig,
    VehicleConfig,
)
from torchpark.compiling import captures, outputs_owned
from torchpark.sim.ring import Counters
from torchpark.sim.state import ParkingState


@pytest.mark.parametrize("num_envs", [1, 5])
def test_check_env_specs(num_envs, device):
    check_env_specs(ParkingEnv(num_envs, seed=0, device=device))


def test_partial_reset_leaves_other_rows_bit_identical(device):
    env = ParkingEnv(16, seed=1, device=device)
    td = env.reset()
    for a in random_actions(16, 5, 0):
        td = env.step(td.set("action", a.to(device)))["next"]
    before = [t.clone() for t in env.state]
    mask = torch.zeros(16, 1, dtype=torch.bool, device=device)
    mask[[2, 7, 11]] = True
    # torchrl's contract: the input carries the un-reset rows' data, the env's _reset
    # returns every row; both must keep the un-reset rows bit for bit.
    own = env._reset(TensorDict({"_reset": mask}, batch_size=[16], device=device))
    keep = ~mask[:, 0]
    for old, new in zip(before, env.state, strict=True):
        assert torch.equal(old[keep], new[keep])
    assert torch.equal(own["observation"][keep], td["observation"][keep])
    env.set_state(ParkingState(*before))
    out = env.reset(td.clone().set("_reset", mask))
    assert torch.equal(out["observation"][keep], td["observation"][keep])
    assert (env.state.steps[~keep] == 0).all() and (env.state.speed[~keep] == 0).all()
    assert not torch.equal(before[0][~keep], env.state.pose[~keep])


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_action_raises(bad, device):
    """The host path's check (reset_in_step's, read later, is in tests/test_ring.py)."""
    env = ParkingEnv(2, seed=0, device=device, reset_in_step=False)
    env.reset()
    before = [t.clone() for t in env.state]
    with pytest.raises(ValueError, match="action must be finite"):
        act(env, [[1.0, 0.0], [bad, 0.0]])
    for old, new in zip(before, env.state, strict=True):  # the bad step was not kept
        assert torch.equal(old, new)


@pytest.mark.parametrize("shape", [(2,), (4, 2), (3, 3), (3, 2, 1)])
def test_wrong_action_shape_raises(shape):
    env = ParkingEnv(3, seed=0)
    env.reset()
    with pytest.raises(ValueError, match=r"action must have shape \(3, 2\)"):
        env._step(TensorDict({"action": torch.zeros(shape)}, batch_size=[]))


def test_a_step_without_an_action_says_so():
    env = ParkingEnv(3, seed=0)
    with pytest.raises(ValueError, match=r"must hold an 'action' tensor of shape \(3, 2\).*"
                                         r"set td\['action'\] before env.step\(td\)"):
        env.step(env.reset())


@pytest.mark.parametrize("n", [0, -1, 2.5, True])
def test_bad_num_envs_raises(n):
    with pytest.raises(ValueError, match="num_envs must be an int >= 1"):
        ParkingEnv(n)


@pytest.mark.parametrize("p", [-0.1, 1.5, float("nan"), "0.5"])
def test_bad_occupancy_raises(p):
    env = ParkingEnv(1)
    with pytest.raises(ValueError, match=r"occupancy must be a number in \[0, 1\]"):
        env.occupancy = p
    wrong_type = isinstance(p, str)  # a type error, not a range error
    with pytest.raises(TypeError if wrong_type else ValueError,
                       match=r"ParkingConfig.occupancy must be a number"):
        ParkingConfig(occupancy=p)


@pytest.mark.parametrize("make, match", [
    (lambda: LidarConfig(n_rays=0), "n_rays"),
    (lambda: LidarConfig(max_range=-1.0), "max_range"),
    (lambda: RewardConfig(success_threshold=0.0), "success_threshold"),
    (lambda: BrakeConfig(penalty=float("nan")), "BrakeConfig.penalty"),
    (lambda: ParkingConfig(max_steps=0), "max_steps"),
])
def test_impossible_configs_raise(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_same_seed_same_rollout_and_other_seed_differs(device):
    actions = random_actions(8, 120, 7).to(device)

    def run(seed):
        env = ParkingEnv(8, seed=seed, device=device)
        env.occupancy = 0.4
        td = env.reset()
        out = [td["observation"]]
        for a in actions:
            td = env.step_and_maybe_reset(TensorDict({**td, "action": a}, batch_size=[8],
                                                     device=device))[1]
            out.append(td["observation"])
        return torch.stack(out)

    first, second = run(11), run(11)
    assert torch.equal(first, second)
    assert not torch.equal(first, run(12))


def test_set_seed_reproduces():
    env = ParkingEnv(4)
    env.set_seed(3)
    a = env.reset()["observation"]
    env.set_seed(3)
    assert torch.equal(a, env.reset()["observation"])


def test_collector_auto_resets_and_keeps_the_extra_keys(device):
    env = TransformedEnv(ParkingEnv(16, seed=8, config=ParkingConfig(max_steps=20),
                                    device=device), InitTracker())
    env.base_env.occupancy = 0.8
    collector = Collector(env, None, frames_per_batch=16 * 25, total_frames=16 * 50)
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 2
    batch = batches[1]
    assert batch.shape == (16, 25)
    nxt = batch["next"]
    assert nxt["done"].any()  # truncation after 20 steps at the latest
    for key in ("success", "collision", "occupancy"):
        assert key in nxt.keys()
    assert (nxt["occupancy"] == 0.8).all()
    # Episodes restart after done: the step counter implied by is_init matches.
    assert batch["is_init"].sum() >= 16


@pytest.mark.xdist_group(COMPILED_GROUP)
@pytest.mark.slow
@pytest.mark.parametrize("config, aids", COMPILED_BUILDS.values(), ids=COMPILED_BUILDS.keys())
def test_compiled_step_is_one_graph_and_matches_eager(config, aids, device):
    """compile_step=True compiles step and reset with fullgraph=True: any graph break raises."""
    actions = random_actions(COMPILED_N, 40, 9).to(device)
    outs = []
    for compiled in (False, True):
        env = ParkingEnv(COMPILED_N, seed=10, config=config, aids=aids, compile_step=compiled,
                         device=device)
        env.occupancy = 0.6
        td = env.reset()
        seq = []
        for a in actions:
            td_out, td = env.step_and_maybe_reset(TensorDict({**td, "action": a},
                                                             batch_size=[COMPILED_N],
                                                             device=device))
            seq.append(td_out["next"].select("observation", "reward", "done", "collision"))
        outs.append(torch.stack(seq))
        if aids is not None and aids.docking is not None:  # the law did drive
            assert env.aid_state.docking_engaged.any()
    eager, compiled = outs
    assert torch.equal(eager["done"], compiled["done"])
    assert torch.equal(eager["collision"], compiled["collision"])
    assert torch.allclose(eager["observation"], compiled["observation"], atol=1e-4)
    assert torch.allclose(eager["reward"], compiled["reward"], atol=1e-3)


def test_a_captured_functions_outputs_are_copied_whole():
    """What a function compiled to replay CUDA graphs returns (tuples, NamedTuples, dicts of
    tensors, other leaves) comes back with the same structure and values in fresh tensors."""
    returned = []

    def function(x):
        returned.append((Counters(x, x + 1), {"twice": 2 * x}, "kept"))
        return returned[-1]

    x = torch.arange(4.0)
    got = outputs_owned(function)(x)
    (counters, twice, word), (counters0, twice0, _) = got, returned[0]
    assert type(counters) is Counters and word == "kept" and set(twice) == {"twice"}
    for copy, original in ((counters.block, counters0.block), (counters.used, counters0.used),
                           (twice["twice"], twice0["twice"])):
        assert torch.equal(copy, original) and copy.data_ptr() != original.data_ptr()


@pytest.mark.parametrize("kwargs, replays", [
    ({}, False), ({"mode": "default"}, False), ({"options": None}, False),
    ({"mode": "reduce-overhead"}, True), ({"mode": "max-autotune"}, True),
    ({"options": {"triton.cudagraphs": True}}, True)])
def test_the_compile_modes_that_replay_cuda_graphs_are_told_apart(kwargs, replays):
    assert captures(kwargs) is replays
    ParkingEnv(2, compile_step=True, compile_kwargs=kwargs)  # builds (compiles on first use)


@pytest.mark.slow
def test_a_capturing_compile_mode_keeps_the_rollout():
    """A compile mode that replays CUDA graphs ("reduce-overhead") has every call's outputs
    copied out of the graphs' memory: through resets inside the step, the rollout of the env
    without it. On a CPU nothing is captured, so dynamo's eager backend (which ignores the
    mode) traces the same functions without inductor's minute; inductor's graphs are the
    compiled == eager test's, the CUDA graphs' replay tests/test_cuda.py's."""
    kwargs = {"backend": "eager", "mode": "reduce-overhead"}
    assert captures(kwargs)
    plain = ParkingEnv(COMPILED_N, seed=1, **RING_BUILD)
    captured = ParkingEnv(COMPILED_N, seed=1, compile_step=True, compile_kwargs=kwargs,
                          **RING_BUILD)
    assert_same_rollout(rollout(captured, 20, seed=2), rollout(plain, 20, seed=2))


@pytest.mark.slow
@pytest.mark.parametrize("aids", [None, AidsConfig(action_repeat=2, brake=BrakeConfig(),
                                                   docking=DockingConfig(),
                                                   observe_position=True)],
                         ids=["paper", "aided"])
def test_step_and_maybe_reset_gives_torchrls_generic_result(aids):
    """ParkingEnv's own step_and_maybe_reset returns the tensordicts of torchrl's generic
    path (EnvBase's), key for key and bit for bit, through partial and full resets, the
    action zeroed in the reset rows as torchrl pads it."""
    short = ParkingConfig(max_steps=3)  # episodes end by truncation too
    ours, generic = (ParkingEnv(16, seed=3, config=short, aids=aids) for _ in range(2))
    td_ours, td_generic = ours.reset(), generic.reset()
    partial = full = 0
    # Standing still first: every row truncates at once (a full reset); then the step
    # counts spread, and rows end at different steps (partial resets).
    for step, action in enumerate(torch.cat((torch.zeros(3, 16, 2),
                                             random_actions(16, 100, 1)))):
        if step == 3:
            ours.randomize_step_counts(), generic.randomize_step_counts()
        out_ours, td_ours = ours.step_and_maybe_reset(td_ours.set("action", action))
        out_generic, td_generic = EnvBase._step_and_maybe_reset(
            generic, td_generic.set("action", action))
        for a, b in ((out_ours, out_generic), (td_ours, td_generic)):
            assert set(a.keys(True, True)) == set(b.keys(True, True))
            assert all(torch.equal(a[k], b[k]) for k in a.keys(True, True))
        done = out_ours["next", "done"]
        partial, full = partial + int(done.any() & ~done.all()), full + int(done.all())
    assert partial > 20 and full > 0


def test_randomize_step_counts_spreads_the_first_timeouts():
    env = ParkingEnv(512, seed=0, config=ParkingConfig(max_steps=100))
    td = env.reset()
    env.randomize_step_counts()
    steps = env.state.steps.clone()
    assert steps.min() >= 0 and steps.max() < 100 and steps.unique().numel() > 50
    other = ParkingEnv(512, seed=0, config=ParkingConfig(max_steps=100))
    other.reset()
    other.randomize_step_counts()
    assert torch.equal(other.state.steps, steps)  # drawn from the env's own generator
    first_end = torch.full((512,), -1)
    for step in range(1, 101):
        td = env.step(td.set("action", torch.zeros(512, 2)))["next"]
        first_end = torch.where((first_end < 0) & td["truncated"][:, 0], step, first_end)
    assert torch.equal(first_end, 100 - steps)


# ---------------------------------------------------------------- hostile input


def test_step_and_render_before_reset_raise():
    env = ParkingEnv(4, seed=0)
    with pytest.raises(RuntimeError, match="before reset"):
        act(env, [1.0, 0.0])
    with pytest.raises(RuntimeError, match="before reset"):
        env.render()
    env.reset()
    with pytest.raises(IndexError, match="indices must be ints"):
        env.render_grid([True])
    assert not act(env, [0.0, 0.0])["success"].any()  # a real lot: nobody starts on the goal


def test_no_autograd_graph_enters_the_state(device):
    env = ParkingEnv(8, seed=0, device=device)
    td = env.reset()
    action = torch.ones(8, 2, device=device, requires_grad=True)
    out = env.step(td.set("action", action * 2.0))["next"]
    assert not any(t.requires_grad for t in env.state)
    assert not any(v.requires_grad for v in out.values(include_nested=True, leaves_only=True))
    rollout = env.rollout(5, lambda td: td.set("action", action * 1.0))  # outside no_grad
    assert not rollout["next", "observation"].requires_grad


def test_action_dtypes_float64_is_rounded_the_others_refused():
    a = (torch.rand(6, 2, dtype=torch.float64) * 2 - 1) * torch.tensor([5.0, 0.785],
                                                                      dtype=torch.float64)
    first, second = ParkingEnv(6, seed=3), ParkingEnv(6, seed=3)
    first.reset(), second.reset()
    assert torch.equal(act(first, a.float())["observation"], act(second, a)["observation"])
    for dtype in (torch.float16, torch.bfloat16, torch.int64, torch.bool):
        with pytest.raises(ValueError, match=f"action must be float32 .* got {dtype}"):
            first.step(TensorDict({"action": a.to(dtype)}, batch_size=[6]))


@pytest.mark.parametrize("seed", [1.5, True, "1", np.bool_(True), -1, 2**64, 2**32])
def test_a_seed_that_is_not_an_int_raises(seed):
    """2**32: torch's CPU generator keeps 32 bits of a seed, so 0 and 2**32 would draw the
    same lots."""
    with pytest.raises(ValueError, match=r"seed must be an int in \[0, 2\*\*32\)"):
        ParkingEnv(2, seed=seed)
    with pytest.raises(ValueError, match=r"seed must be an int in \[0, 2\*\*32\)"):
        ParkingEnv(2, seed=0).set_seed(seed)


def test_numpy_numbers_are_taken_where_python_numbers_are():
    env = ParkingEnv(2, seed=np.int64(4))
    env.occupancy = np.float32(0.5)
    assert env.occupancy == 0.5


def test_the_returned_observation_is_the_callers_own():
    env = ParkingEnv(4, seed=5)
    td = env.reset()
    kept = td["observation"].clone()
    td["observation"].fill_(123.0)  # the caller edits what it got
    none = TensorDict({"_reset": torch.zeros(4, 1, dtype=torch.bool)}, batch_size=[4])
    assert torch.equal(env._reset(none)["observation"], kept)  # the env's own output
    step = act(env, [1.0, 0.2])
    seen = step["observation"].clone()
    step["observation"].fill_(-1.0)
    assert torch.equal(env._reset(none)["observation"], seen)


IMPOSSIBLE = [
    (lambda: ParkingConfig(vehicle=VehicleConfig(length=60.0, wheelbase=50.0)),
     "VehicleConfig"),
    (lambda: ParkingConfig(lot=LotConfig(margin=float("inf"))), "LotConfig.margin"),
]


@pytest.mark.timeout(60)  # a sampling loop without a bound would hang: the timeout fails it
@pytest.mark.parametrize("config, name", IMPOSSIBLE, ids=["huge-car", "infinite-margin"])
def test_an_impossible_lot_fails_fast_naming_the_config(config, name):
    with pytest.raises(ValueError, match=name.replace(".", r"\.")):
        ParkingEnv(1, config=config())


def test_the_demo_follows_its_seed(capsys):
    from torchpark.__main__ import main as demo

    def report(seed: int) -> str:
        demo(["--eager", "--num-envs", "32", "--steps", "40", "--seed", str(seed)])
        return capsys.readouterr().out.splitlines()[-1]  # episodes and mean reward

    assert report(0) == report(0) != report(1)


def test_constructor_flags_and_the_threshold_are_checked_by_type():
    with pytest.raises(TypeError, match="compile_step must be a bool"):
        ParkingEnv(2, compile_step="no")
    with pytest.raises(TypeError, match="validate_actions must be a bool"):
        ParkingEnv(2, validate_actions=1)
    with pytest.raises(TypeError, match="compile_kwargs must be a dict or None"):
        ParkingEnv(2, compile_kwargs=["max-autotune"])
    env = ParkingEnv(np.int64(2), seed=0)
    env.success_threshold = np.float32(1e-3)
    assert env.success_threshold == pytest.approx(1e-3)
    with pytest.raises(ValueError, match="success_threshold must be a finite float > 0"):
        env.success_threshold = True


def test_what_the_step_was_built_from_is_fixed_and_compile_kwargs_are_named():
    env = ParkingEnv(2, seed=0)
    for name, value in (("config", ParkingConfig(max_steps=5)), ("aids", AidsConfig()),
                        ("num_envs", 3), ("layout", None), ("reset_in_step", True),
                        ("compiled", True)):
        with pytest.raises(AttributeError, match=f"ParkingEnv.{name} is fixed at construction"):
            setattr(env, name, value)
    assert env.config == ParkingConfig() and env.aids is None and env.num_envs == 2
    env.validate_actions = False  # read at every step: settable, checked
    with pytest.raises(TypeError, match="validate_actions must be a bool"):
        env.validate_actions = "no"
    for kwargs, match in (({"options": "abc"}, r"compile_kwargs\['options'\] must be a dict"),
                          ({"dynamic": "maybe"}, r"compile_kwargs\['dynamic'\] must be a bool"),
                          ({"mode": "fast"}, r"compile_kwargs\['mode'\] must be one of"),
                          ({"fullgraph": 1}, r"compile_kwargs\['fullgraph'\] must be a bool"),
                          ({"backend": 3}, r"compile_kwargs\['backend'\] must be"),
                          ({"mode": "default", "options": {}}, "'mode' or 'options', not both"),
                          ({"model": None}, r"compile_kwargs may hold \['fullgraph'")):
        with pytest.raises((TypeError, ValueError), match=match):
            ParkingEnv(2, compile_step=True, compile_kwargs=kwargs)
    with pytest.raises(ValueError, match="one CPU device"):
        ParkingEnv(2, device="cpu:1")
    on_zero = ParkingEnv(2, seed=0, device="cpu:0")  # the CPU's one device: "cpu"
    on_zero.reset()
    assert on_zero.device == torch.device("cpu") and on_zero.rollout(2).shape == (2, 2)


def test_an_action_on_another_device_is_refused_by_name():
    env = ParkingEnv(2, seed=0)
    env.reset()
    action = torch.zeros(2, 2, device="meta")
    with pytest.raises(ValueError, match="action must be on the env's device cpu, got meta"):
        env._step(TensorDict({"action": action}, batch_size=[2]))


def test_aided_env_declares_its_aids_outputs_and_passes_the_spec_check(device):
    aids = AidsConfig(action_repeat=2, brake=BrakeConfig(steer_clear=3),
                      docking=DockingConfig(), near_goal_starts=NearGoalStarts())
    env = ParkingEnv(6, seed=0, aids=aids, device=device)
    check_env_specs(env)
    keys = set(env.observation_spec.keys())
    assert {"braked", "interventions", "docking_engaged"} <= keys
    assert not {"braked", "interventions", "docking_engaged"} & set(
        ParkingEnv(2, seed=0).observation_spec.keys())  # the paper's env has none of them
    only_brake = ParkingEnv(2, seed=0, aids=AidsConfig(brake=BrakeConfig()))
    assert "docking_engaged" not in only_brake.observation_spec.keys()


def test_observe_position_emits_the_rear_axle_position_and_changes_nothing_else(device):
    """The "position" key is the state's rear-axle (x, y) after a reset and after each step,
    and the episodes (observations, rewards, ends) are the paper env's of the same seed."""
    paper = ParkingEnv(6, seed=3, device=device)
    seen = ParkingEnv(6, seed=3, device=device, aids=AidsConfig(observe_position=True))
    check_env_specs(ParkingEnv(2, seed=0, device=device, aids=seen.aids))
    assert "position" not in paper.observation_spec.keys()
    assert "position" in seen.observation_spec.keys()
    td, ref = seen.reset(), paper.reset()
    generator = torch.Generator().manual_seed(0)
    for _ in range(30):
        assert torch.equal(td["position"], seen.state.pose[:, :2])
        assert torch.equal(td["observation"], ref["observation"])
        action = (torch.rand(6, 2, generator=generator) * 2 - 1).to(device)
        td = seen.step(td.set("action", action))["next"]
        ref = paper.step(ref.set("action", action))["next"]
        assert torch.equal(td["reward"], ref["reward"]) and torch.equal(td["done"], ref["done"])


def test_set_state_places_rows_and_observes_them():
    env = ParkingEnv(4, seed=0)
    env.reset()
    state = env.state
    moved = state._replace(pose=state.goal.clone(), steps=torch.full_like(state.steps, 3))
    rows = torch.tensor([True, False, True, False])
    td = env.set_state(moved, rows)
    assert torch.equal(env.state.pose[rows], state.goal[rows])
    assert torch.equal(env.state.pose[~rows], state.pose[~rows])
    assert td["observation"][rows, :2].abs().max() == 0  # on the goal: dx = dy = 0
    assert env.state.steps.tolist() == [3, 0, 3, 0]
    with pytest.raises(ValueError, match=r"state.pose must be a torch.float32 tensor of shape"):
        env.set_state(state._replace(pose=torch.zeros(4, 2)))
    with pytest.raises(TypeError, match="state must be a ParkingState"):
        env.set_state(tuple(state))
    for rows in (torch.tensor([1, 0, 1, 0]), torch.ones(3, dtype=torch.bool), [True] * 4):
        with pytest.raises(ValueError, match="rows must be a bool tensor of 4 elements"):
            env.set_state(state, rows)


def test_the_success_threshold_is_set_from_a_number_or_a_tensor():
    env = ParkingEnv(2, seed=0)
    env.set_success_threshold(torch.tensor(0.05))
    assert env.success_threshold == pytest.approx(0.05)
    env.set_success_threshold(1e-3)
    assert env.world.success_threshold.item() == pytest.approx(1e-3)
    with pytest.raises(ValueError, match="0-d float tensor"):
        env.set_success_threshold(torch.tensor([0.1, 0.2]))
    for bad in (torch.tensor(float("nan")), torch.tensor(-1.0), torch.tensor(float("inf"))):
        with pytest.raises(ValueError, match="success_threshold must be a finite float > 0"):
            env.set_success_threshold(bad)
    with pytest.raises(ValueError, match="does not require grad"):
        env.set_success_threshold(torch.tensor(0.1, requires_grad=True))
    assert env.success_threshold == pytest.approx(1e-3)  # none of them was taken
    with pytest.raises(TypeError, match="aids must be an AidsConfig"):
        ParkingEnv(2, aids={"action_repeat": 2})


@pytest.mark.parametrize("aids", [None, AidsConfig(action_repeat=2, brake=BrakeConfig(),
                                                   docking=DockingConfig(),
                                                   near_goal_starts=NearGoalStarts())],
                         ids=["paper", "aided"])
def test_restoring_a_snapshot_replays_the_same_future(aids):
    env = ParkingEnv(16, seed=3, config=ParkingConfig(occupancy=0.7), aids=aids)
    td = env.reset()
    actions = random_actions(16, 40, 1)
    for a in actions[:10]:
        td = env.step_and_maybe_reset(td.set("action", a))[1]
    saved = env.snapshot()
    kept = td.clone()

    def future(td):
        out = []
        for a in actions[10:]:  # episodes end and reset on the way: the generator matters
            step, td = env.step_and_maybe_reset(td.set("action", a))
            out.append(step["next"].exclude("action"))
        return torch.stack(out)

    first = future(td)
    env.restore(saved)
    assert (future(kept) == first).all()
    with pytest.raises(TypeError, match=r"snapshot must be a dict from ParkingEnv\.snapshot"):
        env.restore(list(saved.items()))
    with pytest.raises(ValueError, match="snapshot must hold exactly"):
        env.restore({k: v for k, v in saved.items() if k != "generator"})
    with pytest.raises(ValueError, match=r"snapshot\['observation'\] must be a torch.float32"):
        env.restore({**saved, "observation": saved["observation"][:3]})


@pytest.mark.slow
def test_a_process_builds_as_many_compiled_envs_as_it_likes():
    """torch.compile caches every compiled partial under one wrapper, 8 graphs by default:
    the third compiled env of a fresh process used to fail (fullgraph=True). A limit of
    dynamo's, whatever the backend: its eager one traces the builds without inductor."""
    code = ("import torch\nfrom torchpark import ParkingEnv\n"
            "from tests.conftest import COMPILED_BUILDS, COMPILED_N, RING_BUILD\n"
            "builds = [{'config': c, 'aids': a} for c, a in COMPILED_BUILDS.values()]\n"
            "for i, build in enumerate([*builds, RING_BUILD]):\n"
            "    env = ParkingEnv(COMPILED_N, seed=i, compile_step=True,\n"
            "                     compile_kwargs={'backend': 'eager'}, **build)\n"
            "    env.reset(); env.rand_step(); env.reset()\n"
            "print('ok', torch._dynamo.config.recompile_limit)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=600, cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0 and done.stdout.split() == ["ok", "256"], done.stderr[-800:]


def _equal_snapshots(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        torch.equal(a[k], b[k]) if isinstance(a[k], torch.Tensor) else a[k] == b[k] for k in a)


def test_a_snapshot_from_before_a_config_field_existed_restores_at_its_default():
    """A snapshot's build that lacks a field added since (collision_substeps) is read as the
    field's default: restored into an env at the default, refused by name by one that is
    not."""
    env = ParkingEnv(4, seed=1)
    env.reset()
    older = env.snapshot()
    del older["build"]["config"]["collision_substeps"]
    env.rand_step()
    env.restore(older)
    assert torch.equal(env.state.pose, older["state.pose"])
    swept = ParkingEnv(4, seed=1, config=ParkingConfig(collision_substeps=8))
    with pytest.raises(ValueError, match=r"config\.collision_substeps=1 in the snapshot, 8 "
                                         r"here"):
        swept.restore(older)


def test_restore_checks_everything_before_writing_anything():
    """A snapshot that does not fit is refused by name, the env left exactly as it was."""
    aids = AidsConfig(brake=BrakeConfig())
    env = ParkingEnv(4, seed=1, aids=aids)
    env.reset()
    saved = env.snapshot()
    env.rand_step()
    before = env.snapshot()
    noise = torch.randint(0, 256, saved["generator"].shape, dtype=torch.uint8,
                          generator=torch.Generator().manual_seed(0))
    other_lot = ParkingEnv(4, seed=1, aids=aids,
                           config=ParkingConfig(lot=LotConfig(slot_width=2.6)))
    other_lot.reset()
    bad = [
        ({**saved, "occupancy": 1.5}, ValueError, r"snapshot\['occupancy'\] must be a number "
                                                  r"in \[0, 1\], got 1.5"),
        ({**saved, "started": 1}, TypeError, r"snapshot\['started'\] must be a bool"),
        ({**saved, "generator": noise}, ValueError, r"snapshot\['generator'\] is not a state "
                                                    r"of this device's random generator"),
        ({**saved, "state.pose": torch.full((4, 3), float("nan"))}, ValueError,
         r"snapshot\['state'\]\.pose must be finite"),
        ({**saved, "ahead.state.goal_slot": torch.full((4,), 999)}, ValueError,
         r"snapshot\['ahead\.state'\]\.goal_slot must be a slot index in \[0, 38\)"),
        ({**saved, "aids.interventions": torch.full((4,), -1)}, ValueError,
         r"snapshot\['state'\]\.aids\.interventions must be >= 0"),
        ({**saved, "success_threshold": torch.tensor(-1.0)}, ValueError,
         r"snapshot\['success_threshold'\] must be a finite number > 0"),
        (other_lot.snapshot(), ValueError, r"snapshot\['build'\] is of an env built "
                                           r"otherwise: config\.lot\.slot_width=2\.6 in the "
                                           r"snapshot, 2\.5 here"),
        (ParkingEnv(4, seed=1).snapshot(), ValueError,
         r"built otherwise: aids\.brake=None in the snapshot"),
        ({k: v for k, v in saved.items() if k != "cost"}, ValueError,
         r"snapshot must hold exactly .*missing \['cost'\]"),
    ]
    for snapshot, kind, message in bad:
        with pytest.raises(kind, match=message):
            env.restore(snapshot)
        assert _equal_snapshots(env.snapshot(), before)
    env.restore(saved)
    assert _equal_snapshots(env.snapshot(), saved)


def test_set_state_refuses_what_no_episode_holds_and_rows_without_a_lot():
    env = ParkingEnv(4, seed=0)
    with pytest.raises(RuntimeError, match="set_state before reset must set every row"):
        env.set_state(ParkingState.zeros(4, env.world.obstacles.cx.shape[0], "cpu"),
                      torch.tensor([True, False, True, True]))
    with pytest.raises(RuntimeError, match="step before reset"):
        env.rand_step()  # the refused set_state started nothing
    env.reset()
    state, before = env.state, env.snapshot()
    for bad, message in ((state._replace(pose=torch.full((4, 3), float("nan"))),
                          r"state\.pose must be finite"),
                         (state._replace(goal_slot=torch.full((4,), 999)),
                          r"state\.goal_slot must be a slot index in \[0, 38\)"),
                         (state._replace(present=torch.full_like(state.present, 0.5)),
                          r"state\.present must be 0 or 1")):
        with pytest.raises(ValueError, match=message):
            env.set_state(bad)
        assert _equal_snapshots(env.snapshot(), before)


@pytest.mark.parametrize("device", ["meta", "cuda:99", "nonsense"])
def test_a_device_this_machine_lacks_is_one_line(device):
    with pytest.raises(ValueError, match=r"^device (must be a torch device|is 'cuda:99', but "
                                         r"torch sees)"):
        ParkingEnv(1, device=device)


@pytest.mark.parametrize(("argv", "message"), [
    (["--steps", "0"], "--steps must be in [1, 10000000]"),
    (["--seed", str(2**32)], "--seed must be an int in [0, 2**32)"),
    (["--num-envs", "0"], "num_envs must be an int >= 1"),
    (["--device", "meta"], "device must be a torch device"),
    (["--occupancy", "1.5"], "occupancy must be a number in [0, 1]"),
])
def test_the_demo_refuses_bad_arguments_in_one_line(argv, message, capsys):
    from torchpark.__main__ import main as demo

    with pytest.raises(SystemExit) as refused:
        demo(["--eager", *argv])
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert refused.value.code == 2 and "Traceback" not in err
    assert last.startswith("python -m torchpark: error: ") and message in last, err


def test_without_a_cxx_compiler_a_compiled_env_warns_once_and_runs_eager(capsys):
    """torch.compile's CPU backend needs a C++ compiler: where torch finds none (here, a
    search for one that does not exist), compile_step=True is one warning line and an eager
    env that steps, and ``python -m torchpark`` says so in one line."""
    from torch._inductor import config as inductor

    import torchpark.__main__ as demo
    from torchpark import compiling

    with inductor.patch({"cpp.cxx": ("no-such-compiler-for-torchpark",)}):
        assert not compiling.compiler_found()
        with pytest.warns(RuntimeWarning, match="runs eager: torch.compile needs a C\\+\\+ "
                                                "compiler and none was found") as caught:
            env = ParkingEnv(4, seed=0, compile_step=True)
        assert len(caught) == 1 and not env.compiled
        assert env.rollout(3, break_when_any_done=False)["next", "observation"].shape \
            == (4, 3, 23)
        demo.main(["--num-envs", "4", "--steps", "2"])
    out = capsys.readouterr().out
    assert "no C++ compiler found (install g++ or set CXX): the step runs eager" in out
    assert "compiling" not in out
    assert compiling.compiler_found() == bool(shutil.which("g++") or shutil.which("clang++")
                                               or os.environ.get("CXX"))
