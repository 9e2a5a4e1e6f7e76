"""ParkingEnv behaviour: specs, resets, reward, termination, input checks, determinism."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs import InitTracker, TransformedEnv
from torchrl.envs.utils import check_env_specs

from torchpark import (
    DockingConfig,
    LidarConfig,
    LotConfig,
    ParkingConfig,
    ParkingEnv,
    RewardConfig,
)
from torchpark.simulation import ParkingState, touches_obstacle
from torchpark.vehicle import bicycle_step, vehicle_frame


def place(env: ParkingEnv, pose: torch.Tensor, rows: torch.Tensor | slice = slice(None)) -> None:
    """Teleport the rear axle of ``rows`` to ``pose`` (test helper)."""
    new = env.state.pose.clone()
    new[rows] = pose
    env._state = env.state._replace(pose=new)


def act(env: ParkingEnv, action) -> TensorDict:
    action = torch.as_tensor(action, dtype=torch.float32, device=env.device)
    return env.step(TensorDict({"action": action.expand(env.num_envs, 2)},
                               batch_size=env.batch_size, device=env.device))["next"]


def random_actions(n: int, steps: int, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(steps, n, 2, generator=gen) * 2 - 1) * torch.tensor([5.0, 0.785])


@pytest.mark.parametrize("num_envs", [1, 5])
def test_check_env_specs(num_envs, device):
    check_env_specs(ParkingEnv(num_envs, seed=0, device=device))


def test_observation_layout_at_reset():
    env = ParkingEnv(4, seed=0)
    obs = env.reset()["observation"]
    s = env.state
    assert obs.shape == (4, 23) and obs.dtype == torch.float32
    assert torch.allclose(obs[:, 0], s.goal[:, 0] - s.pose[:, 0])
    assert torch.allclose(obs[:, 1], s.goal[:, 1] - s.pose[:, 1])
    assert torch.allclose(obs[:, 2], torch.cos(s.pose[:, 2]))
    assert torch.allclose(obs[:, 3], torch.sin(s.pose[:, 2]))
    assert (obs[:, 4] == 0).all()
    assert torch.allclose(obs[:, 5], torch.cos(s.goal[:, 2]))
    assert ((obs[:, 7:] >= 0) & (obs[:, 7:] <= 1)).all()


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
    env._state = ParkingState(*before)
    out = env.reset(td.clone().set("_reset", mask))
    assert torch.equal(out["observation"][keep], td["observation"][keep])
    assert (env.state.steps[~keep] == 0).all() and (env.state.speed[~keep] == 0).all()
    assert not torch.equal(before[0][~keep], env.state.pose[~keep])


def test_reward_recomputed_from_observation(device):
    env = ParkingEnv(32, seed=2, device=device)
    env.occupancy = 0.6
    rollout = env.rollout(60, policy=None, break_when_any_done=False).cpu()
    nxt = rollout["next"]
    obs, reward = nxt["observation"], nxt["reward"][..., 0]
    live = ~nxt["terminated"][..., 0]
    assert live.sum() > 1000
    psi = torch.atan2(obs[..., 3], obs[..., 2])
    alpha = torch.atan2(obs[..., 6], obs[..., 5])
    dalpha = torch.remainder(alpha - psi + math.pi, 2 * math.pi) - math.pi
    cost = (0.35 * obs[..., 0].abs() + 0.35 * obs[..., 1].abs() + 0.2 * dalpha.abs()
            + 0.1 * obs[..., 4].abs())
    expected = 1 - cost ** (1 / 3)
    assert torch.allclose(reward[live], expected[live], atol=1e-5)
    collided = nxt["collision"][..., 0]
    assert collided.any()
    assert torch.allclose(reward[collided], expected[collided] - 200, atol=1e-4)


def test_driving_into_a_wall_collides_and_terminates():
    env = ParkingEnv(1, seed=0)
    env.reset()
    width = env.layout.width
    # Facing +x, front bumper 0.3 m from the right wall; on the bottom lane, away from slots.
    place(env, torch.tensor([width - 4.5 - 0.3, 3.0, 0.0]))
    first = act(env, [2.0, 0.0])  # 0.2 m: still clear
    assert not first["collision"].item() and not first["done"].item()
    second = act(env, [2.0, 0.0])  # 0.4 m: through the wall line
    assert second["collision"].item() and second["terminated"].item() and second["done"].item()
    assert not second["truncated"].item()
    obs = second["observation"][0].tolist()
    cost = 0.35 * abs(obs[0]) + 0.35 * abs(obs[1]) + 0.1 * 2.0 + 0.2 * abs(
        math.remainder(math.atan2(obs[6], obs[5]) - math.atan2(obs[3], obs[2]), 2 * math.pi))
    assert second["reward"].item() == pytest.approx(1 - cost ** (1 / 3) - 200, abs=1e-4)


def test_standing_in_an_empty_slot_is_no_collision_but_a_parked_car_is():
    env = ParkingEnv(2, seed=0)
    env.occupancy = 0.5
    env.reset()
    present = env.state.present[:, : env.layout.num_slots]
    empty = int(torch.nonzero((present[0] == 0) & (torch.arange(present.shape[1]) !=
                                                   env.state.goal_slot[0]))[0])
    full = int(torch.nonzero(present[1] == 1)[0])
    place(env, env.layout.goal_poses[[empty, full]])
    out = act(env, [0.0, 0.0])
    assert out["collision"][:, 0].tolist() == [False, True]


def test_touching_the_wall_counts():
    env = ParkingEnv(1, seed=0)
    env.reset()
    place(env, torch.tensor([env.layout.width - 4.5 - 0.25, 3.0, 0.0]))
    assert act(env, [2.5, 0.0])["collision"].item()  # front exactly on the wall's face


def test_placing_the_car_on_its_goal_succeeds():
    env = ParkingEnv(8, seed=3)
    env.occupancy = 0.9
    env.reset()
    place(env, env.state.goal)
    out = act(env, [0.0, 0.0])
    assert out["success"].all() and out["terminated"].all() and not out["collision"].any()
    assert torch.allclose(out["reward"], torch.full((8, 1), 1001.0))


def test_driving_onto_the_goal_succeeds_within_threshold():
    env = ParkingEnv(4, seed=4)
    env.reset()
    goal = env.state.goal
    back = torch.stack((torch.cos(goal[:, 2]), torch.sin(goal[:, 2])), -1) * 1e-4
    place(env, torch.cat((goal[:, :2] - back, goal[:, 2:]), -1))
    out = act(env, [1e-3, 0.0])  # 0.1 mm forward at 1 mm/s: C ~ 1e-4 < 4e-4
    assert out["success"].all()
    assert (out["reward"] > 1000.9).all()


def test_truncation_at_step_limit():
    env = ParkingEnv(3, seed=5, config=ParkingConfig(max_steps=7))
    env.reset()
    for step in range(1, 8):
        out = act(env, [0.0, 0.0])  # standing still: no collision, no success
        assert out["truncated"].all() == (step == 7)
        assert out["done"].all() == (step == 7) and not out["terminated"].any()


def test_out_of_range_actions_are_clamped():
    a, b = ParkingEnv(2, seed=6), ParkingEnv(2, seed=6)
    a.reset(), b.reset()
    out_a = act(a, [[50.0, 3.0], [-50.0, -3.0]])
    out_b = act(b, [[5.0, 0.785], [-5.0, -0.785]])
    assert torch.equal(out_a["observation"], out_b["observation"])


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_action_raises(bad, device):
    env = ParkingEnv(2, seed=0, device=device)
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
    (lambda: RewardConfig(brake_penalty=float("nan")), "brake_penalty"),
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


def test_n_rays_option_changes_the_observation():
    env = ParkingEnv(2, seed=0, config=ParkingConfig(lidar=LidarConfig(n_rays=32)))
    assert env.reset()["observation"].shape == (2, 39)
    check_env_specs(ParkingEnv(2, seed=0, config=ParkingConfig(lidar=LidarConfig(n_rays=5))))


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
    for key in ("success", "collision", "braked", "occupancy"):
        assert key in nxt.keys()
    assert (nxt["occupancy"] == 0.8).all()
    # Episodes restart after done: the step counter implied by is_init matches.
    assert batch["is_init"].sum() >= 16


@pytest.mark.parametrize("config", [
    ParkingConfig(),
    ParkingConfig(lot=LotConfig(near_goal_starts=0.5), docking=DockingConfig(lateral=1.0,
                                                                              heading=0.6)),
    ParkingConfig(occupancy=0.9, emergency_brake=True, steer_clear=5,
                  lot=LotConfig(near_goal_starts=0.5), docking=DockingConfig()),
], ids=["paper", "docking", "steer-clear"])
def test_compiled_step_is_one_graph_and_matches_eager(config, device):
    """compile_step=True compiles step and reset with fullgraph=True: any graph break raises."""
    actions = random_actions(64, 40, 9).to(device)
    outs = []
    for compiled in (False, True):
        env = ParkingEnv(64, seed=10, config=config, compile_step=compiled, device=device)
        env.occupancy = 0.6
        td = env.reset()
        seq = []
        for a in actions:
            td_out, td = env.step_and_maybe_reset(TensorDict({**td, "action": a}, batch_size=[64],
                                                             device=device))
            seq.append(td_out["next"].select("observation", "reward", "done", "collision"))
        outs.append(torch.stack(seq))
        assert config.docking is None or env.state.docking.any()  # the layer did drive
    eager, compiled = outs
    assert torch.equal(eager["done"], compiled["done"])
    assert torch.equal(eager["collision"], compiled["collision"])
    assert torch.allclose(eager["observation"], compiled["observation"], atol=1e-4)
    assert torch.allclose(eager["reward"], compiled["reward"], atol=1e-3)


def test_action_repeat_equals_single_steps_and_stops_at_the_end():
    k = 4
    single = ParkingEnv(32, seed=9, config=ParkingConfig(occupancy=0.9))
    held = ParkingEnv(32, seed=9, config=ParkingConfig(occupancy=0.9, action_repeat=k))
    a, b = single.reset(), held.reset()
    assert torch.equal(a["observation"], b["observation"])
    action = torch.tensor([[3.0, 0.4]]).expand(32, 2)
    ended = torch.zeros(32, dtype=torch.bool)
    reward = torch.zeros(32)
    observation = a["observation"].clone()
    collided = torch.zeros(32, dtype=torch.bool)
    for _ in range(k):
        out = single.step(a.set("action", action))["next"]
        live = ~ended
        reward += torch.where(live, out["reward"][:, 0], 0.0)
        observation[live] = out["observation"][live]
        collided |= live & out["collision"][:, 0]
        ended |= out["done"][:, 0]
        a = out
    out = held.step(b.set("action", action))["next"]
    assert collided.any() and not collided.all()  # some rows end inside the held action
    assert torch.allclose(out["reward"][:, 0], reward, atol=1e-4)
    assert torch.allclose(out["observation"], observation, atol=1e-5)
    assert torch.equal(out["collision"][:, 0], collided)
    assert torch.equal(held.state.steps, torch.where(collided, held.state.steps, k))


def test_emergency_brake_never_collides_and_holds_the_pose(device):
    env = ParkingEnv(64, seed=2, config=ParkingConfig(occupancy=0.9, emergency_brake=True),
                     device=device)
    td = env.reset()
    plain = ParkingEnv(64, seed=2, config=ParkingConfig(occupancy=0.9), device=device)
    plain.reset()
    action = torch.tensor([[5.0, 0.3]], device=device).expand(64, 2)
    for _ in range(100):
        before = env.state.pose.clone()
        td = env.step(td.set("action", action))["next"]
        stopped = env.state.speed == 0
        assert not td["collision"].any() and not td["done"].any()
        assert torch.equal(env.state.pose[stopped], before[stopped])
    assert stopped.all()  # full throttle ends against something everywhere
    hits = 0
    td = plain.reset()
    for _ in range(100):
        td = plain.step(td.set("action", action))["next"]
        hits += int(td["collision"].sum())
    assert hits > 0  # the same drive without the brake collides


def test_steer_clear_takes_the_clear_steering_nearest_the_commanded_else_stops():
    """Random actions in dense lots, every colliding step checked against a search over the
    five angles: the step is taken at the clear angle nearest the commanded one, at the
    commanded speed; with none clear the car stops; either way it counts as braked."""
    env = ParkingEnv(64, seed=2, config=ParkingConfig(occupancy=0.9, emergency_brake=True,
                                                      steer_clear=5))
    td = env.reset()
    generator = torch.Generator().manual_seed(0)
    spread = torch.linspace(-0.785, 0.785, 5)
    limits = torch.tensor([5.0, 0.785])
    vehicle = env.config.vehicle
    steered = stopped = 0
    for _ in range(60):
        action = (torch.rand(64, 2, generator=generator) * 2 - 1) * limits
        before, brakes = env.state.pose.clone(), env.state.brakes.clone()
        # Commanded angle first, then the five: (64, 6) would-be collisions.
        deltas = torch.cat((action[:, 1:], spread.expand(64, 5)), dim=1)
        poses = bicycle_step(before[:, None].expand(64, 6, 3), action[:, :1].expand(64, 6),
                             deltas, vehicle)
        hits = touches_obstacle(vehicle_frame(poses, vehicle), env._world,
                                env.state.present[:, None])
        td = env.step(td.set("action", action))["next"]
        assert not td["collision"].any()
        assert torch.equal(td["braked"][:, 0], env.state.braked)
        for row in range(64):
            if not hits[row, 0]:
                expected = bicycle_step(before[row], action[row, 0], action[row, 1], vehicle)
                assert torch.equal(env.state.pose[row], expected)
                assert env.state.brakes[row] == brakes[row]
                continue
            assert env.state.brakes[row] == brakes[row] + 1
            clear = [d for d, hit in zip(spread, hits[row, 1:], strict=True) if not hit]
            if clear:
                nearest = min(clear, key=lambda d: abs(float(d - action[row, 1])))
                expected = bicycle_step(before[row], action[row, 0], nearest, vehicle)
                assert torch.allclose(env.state.pose[row], expected, atol=1e-6)
                assert env.state.speed[row] == action[row, 0] and not env.state.braked[row]
                steered += 1
            else:
                assert torch.equal(env.state.pose[row], before[row])
                assert env.state.speed[row] == 0 and env.state.braked[row]
                stopped += 1
    assert steered > 20 and stopped > 5


@pytest.mark.parametrize("value, brake", [(1, True), (-1, True), (True, True), (5, False)])
def test_bad_steer_clear_raises(value, brake):
    with pytest.raises(TypeError if isinstance(value, bool) else ValueError,
                       match=r"ParkingConfig\.steer_clear"):
        ParkingConfig(emergency_brake=brake, steer_clear=value)


def test_brake_penalty_is_added_on_braked_steps_only():
    def drive(penalty: float) -> tuple[list[torch.Tensor], list[torch.Tensor], torch.Tensor]:
        config = ParkingConfig(occupancy=0.9, emergency_brake=True,
                               reward=RewardConfig(brake_penalty=penalty))
        env = ParkingEnv(64, seed=2, config=config)
        td = env.reset()
        rewards, braked = [], []
        action = torch.tensor([[5.0, 0.3]]).expand(64, 2)
        for _ in range(60):
            td = env.step(td.set("action", action))["next"]
            rewards.append(td["reward"][:, 0])
            braked.append(env.state.speed == 0)  # full throttle: speed 0 only when braked
            assert torch.equal(env.state.braked, braked[-1])
        return rewards, braked, env.state.brakes

    plain, braked, brakes = drive(0.0)
    penalised, same, _ = drive(-3.0)
    assert torch.equal(brakes, torch.stack(braked).sum(0))  # the episode's count
    assert all(torch.equal(a, b) for a, b in zip(braked, same, strict=True))
    for r0, r1, b in zip(plain, penalised, braked, strict=True):
        assert torch.allclose(r1, r0 + torch.where(b, -3.0, 0.0))
    assert any(b.any() for b in braked) and not all(b.all() for b in braked)


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


@pytest.mark.parametrize("seed", [1.5, True, "1", np.bool_(True), -1, 2**64])
def test_a_seed_that_is_not_an_int_raises(seed):
    with pytest.raises(ValueError, match=r"seed must be an int in \[0, 2\*\*63\) or None"):
        ParkingEnv(2, seed=seed)


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
    ("vehicle=VehicleConfig(length=60.0, wheelbase=50.0)", "VehicleConfig"),
    ("lot=LotConfig(margin=float('inf'))", "LotConfig.margin"),
]


@pytest.mark.parametrize("config, name", IMPOSSIBLE, ids=["huge-car", "infinite-margin"])
def test_an_impossible_lot_fails_fast_naming_the_config(config, name):
    """In a subprocess with a timeout: a sampling loop without a bound would hang."""
    code = f"from torchpark import *\nParkingEnv(1, config=ParkingConfig({config}))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode != 0
    assert "ValueError" in done.stderr and name in done.stderr, done.stderr[-500:]


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


def test_an_action_on_another_device_is_refused_by_name():
    env = ParkingEnv(2, seed=0)
    env.reset()
    action = torch.zeros(2, 2, device="meta")
    with pytest.raises(ValueError, match="action must be on the env's device cpu, got meta"):
        env._step(TensorDict({"action": action}, batch_size=[2]))
