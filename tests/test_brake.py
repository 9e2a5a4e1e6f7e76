"""The emergency brake (torchpark.aids.brake): it never lets the car collide, steers clear
to the nearest clear angle, keeps its margin, counts its interventions, and adds its penalty
to each."""

from __future__ import annotations

import pytest
import torch

from torchpark import AidsConfig, BrakeConfig, ParkingConfig, ParkingEnv, VehicleConfig
from torchpark.aids.brake import fence, goal_room
from torchpark.sim.vehicle import bicycle_step, vehicle_obb
from torchpark.sim.world import touches_obstacle


# Seeds 1 and 4 draw lots where some car's circle is clear (a CUDA generator draws others).
@pytest.mark.parametrize("seed", [1, 2, 4])
def test_emergency_brake_never_collides_and_holds_the_pose(seed, device):
    """Full throttle on a fixed turn in dense lots, beside the same lots without the brake:
    the braked car never collides, a stopped car holds its pose, and it is stopped exactly
    in the lots where the unbraked drive collides (both drive the same path until then; a
    car whose circle is clear drives on, so no draw of lots can make every car stop)."""
    env = ParkingEnv(64, seed=seed, config=ParkingConfig(occupancy=0.9),
                     aids=AidsConfig(brake=BrakeConfig()), device=device)
    plain = ParkingEnv(64, seed=seed, config=ParkingConfig(occupancy=0.9), device=device)
    td, td_plain = env.reset(), plain.reset()
    assert all(torch.equal(a, b) for a, b in zip(env.state, plain.state, strict=True))  # same lots
    action = torch.tensor([[5.0, 0.3]], device=device).expand(64, 2)
    collided = torch.zeros(64, dtype=torch.bool, device=device)
    for _ in range(100):
        before = env.state.pose.clone()
        td = env.step(td.set("action", action))["next"]
        stopped = env.state.speed == 0
        assert not td["collision"].any() and not td["done"].any()
        assert torch.equal(env.state.pose[stopped], before[stopped])
        td_plain = plain.step(td_plain.set("action", action))["next"]
        collided |= td_plain["collision"][:, 0]
    assert collided.any()  # the same drive without the brake collides
    assert torch.equal(stopped, collided)


def test_steer_clear_takes_the_clear_steering_nearest_the_commanded_else_stops():
    """Random actions in dense lots, every colliding step checked against a search over the
    five angles: the step is taken at the clear angle nearest the commanded one, at the
    commanded speed; with none clear the car stops; either way it counts as braked."""
    env = ParkingEnv(64, seed=2, config=ParkingConfig(occupancy=0.9),
                     aids=AidsConfig(brake=BrakeConfig(steer_clear=5)))
    td = env.reset()
    generator = torch.Generator().manual_seed(0)
    spread = torch.linspace(-0.785, 0.785, 5)
    limits = torch.tensor([5.0, 0.785])
    vehicle = env.config.vehicle
    steered = stopped = 0
    for _ in range(60):
        action = (torch.rand(64, 2, generator=generator) * 2 - 1) * limits
        before, count = env.state.pose.clone(), env.aid_state.interventions.clone()
        # Commanded angle first, then the five: (64, 6) would-be collisions.
        deltas = torch.cat((action[:, 1:], spread.expand(64, 5)), dim=1)
        poses = bicycle_step(before[:, None].expand(64, 6, 3), action[:, :1].expand(64, 6),
                             deltas, vehicle)
        hits = touches_obstacle(vehicle_obb(poses, vehicle), env.world,
                                env.state.present[:, None])
        td = env.step(td.set("action", action))["next"]
        assert not td["collision"].any()
        assert torch.equal(td["braked"][:, 0], env.aid_state.braked)
        assert torch.equal(td["interventions"][:, 0], env.aid_state.interventions)
        for row in range(64):
            if not hits[row, 0]:
                expected = bicycle_step(before[row], action[row, 0], action[row, 1], vehicle)
                assert torch.equal(env.state.pose[row], expected)
                assert env.aid_state.interventions[row] == count[row]
                continue
            assert env.aid_state.interventions[row] == count[row] + 1
            clear = [d for d, hit in zip(spread, hits[row, 1:], strict=True) if not hit]
            if clear:
                nearest = min(clear, key=lambda d: abs(float(d - action[row, 1])))
                expected = bicycle_step(before[row], action[row, 0], nearest, vehicle)
                assert torch.allclose(env.state.pose[row], expected, atol=1e-6)
                assert env.state.speed[row] == action[row, 0] and not env.aid_state.braked[row]
                steered += 1
            else:
                assert torch.equal(env.state.pose[row], before[row])
                assert env.state.speed[row] == 0 and env.aid_state.braked[row]
                stopped += 1
    assert steered > 20 and stopped > 5


@pytest.mark.parametrize("value", [1, -1, True, 2000])
def test_bad_steer_clear_raises(value):
    with pytest.raises(TypeError if isinstance(value, bool) else ValueError,
                       match=r"BrakeConfig\.steer_clear"):
        BrakeConfig(steer_clear=value)


@pytest.mark.parametrize("steer_clear", [0, 5])
def test_brake_penalty_is_added_on_the_steps_it_stops_or_steers(steer_clear):
    def drive(penalty: float) -> tuple[list[torch.Tensor], list[torch.Tensor],
                                       list[torch.Tensor], torch.Tensor]:
        brake = BrakeConfig(steer_clear=steer_clear, penalty=penalty)
        env = ParkingEnv(64, seed=2, config=ParkingConfig(occupancy=0.9),
                         aids=AidsConfig(brake=brake))
        td = env.reset()
        rewards, braked, intervened = [], [], []
        count = torch.zeros(64, dtype=torch.int64)
        action = torch.tensor([[5.0, 0.3]]).expand(64, 2)
        for _ in range(60):
            td = env.step(td.set("action", action))["next"]
            rewards.append(td["reward"][:, 0])
            braked.append(env.state.speed == 0)  # full throttle: speed 0 only when braked
            assert torch.equal(env.aid_state.braked, braked[-1])
            intervened.append(env.aid_state.interventions > count)
            count = env.aid_state.interventions
        return rewards, braked, intervened, count

    plain, braked, intervened, brakes = drive(0.0)
    penalised, _, same, _ = drive(-3.0)
    assert torch.equal(brakes, torch.stack(intervened).sum(0))  # the episode's count
    assert all(torch.equal(a, b) for a, b in zip(intervened, same, strict=True))
    for r0, r1, b in zip(plain, penalised, intervened, strict=True):
        assert torch.allclose(r1, r0 + torch.where(b, -3.0, 0.0))
    stopped, steered = torch.stack(braked), torch.stack(intervened) & ~torch.stack(braked)
    assert stopped.any() and not stopped.all()
    assert bool(steered.any()) == (steer_clear > 0)  # steering clear is penalised as well


@pytest.mark.parametrize("steer_clear", [0, 5])
def test_brake_keeps_its_margin(steer_clear):
    """Random driving at 90 %: with a 0.2 m margin no step that starts with the box grown by
    0.2 m clear of every obstacle ends with it touching one, and nothing collides; the same
    drive on the exact test (margin 0) comes that close, so the margin is what keeps it off."""
    entered, interventions = {}, {}
    for margin in (0.0, 0.2):
        env = ParkingEnv(64, seed=3, config=ParkingConfig(occupancy=0.9), aids=AidsConfig(
            brake=BrakeConfig(steer_clear=steer_clear, margin=margin)))
        td = env.reset()
        generator = torch.Generator().manual_seed(0)
        entered[margin] = 0
        for _ in range(60):
            action = (torch.rand(64, 2, generator=generator) * 2 - 1) * torch.tensor([5.0, 0.785])
            clear = ~touches_obstacle(fence(env.state.pose, env.config.vehicle, 0.2), env.world,
                                      env.state.present)
            td = env.step(td.set("action", action))["next"]
            assert not td["collision"].any() and not td["done"].any()
            close = touches_obstacle(fence(env.state.pose, env.config.vehicle, 0.2), env.world,
                                     env.state.present)
            entered[margin] += int((clear & close).sum())
        interventions[margin] = int(env.aid_state.interventions.sum())
    assert entered[0.2] == 0 < entered[0.0]
    assert interventions[0.2] > interventions[0.0]


def test_fence_is_the_box_of_a_car_grown_on_every_side():
    poses = torch.tensor([[1.0, 2.0, 0.3], [-4.0, 0.5, -2.8]])
    wide = VehicleConfig(width=2.5, length=5.5, rear_overhang=0.75)  # 0.25 m more each side
    for got, want in zip(fence(poses, VehicleConfig(), 0.25), vehicle_obb(poses, wide),
                         strict=True):
        assert torch.allclose(got, want)


def test_a_margin_the_goal_breaks_is_refused():
    """The paper's lot leaves a parked car 0.25 m to its neighbour's slot on each side: 0.5 m
    to the neighbour's car. A margin that the goal pose itself breaks (at the angled slots'
    corners, from 0.43 m) would stop every docking there, and is refused by name."""
    env = ParkingEnv(1, aids=AidsConfig(brake=BrakeConfig(margin=0.4)))
    assert goal_room(env.world, env.config.vehicle) == pytest.approx(0.5, abs=1e-5)
    assert goal_room(env.world, env.config.vehicle, 0.4) > 0
    with pytest.raises(ValueError, match=r"BrakeConfig\.margin must be below 0\.42\d m"):
        ParkingEnv(1, aids=AidsConfig(brake=BrakeConfig(margin=0.6)))


@pytest.mark.parametrize("value", [-0.1, float("nan"), float("inf"), 1.5, True])
def test_bad_margin_raises(value):
    with pytest.raises(TypeError if isinstance(value, bool) else ValueError,
                       match=r"BrakeConfig\.margin"):
        BrakeConfig(margin=value)
