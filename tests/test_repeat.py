"""Held actions (torchpark.aids.repeat): k held steps equal k single steps, stopping at the
episode's end."""

from __future__ import annotations

import torch

from torchpark import AidsConfig, ParkingConfig, ParkingEnv


def test_action_repeat_equals_single_steps_and_stops_at_the_end():
    k = 4
    single = ParkingEnv(32, seed=9, config=ParkingConfig(occupancy=0.9))
    held = ParkingEnv(32, seed=9, config=ParkingConfig(occupancy=0.9),
                      aids=AidsConfig(action_repeat=k))
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
    # The held steps skip the LIDAR but the last observation is the state's, bit for bit.
    assert torch.equal(out["observation"], observation)
    assert torch.equal(out["collision"][:, 0], collided)
    assert torch.equal(held.state.steps, torch.where(collided, held.state.steps, k))
