"""The specs of ``ParkingEnv``: what its steps take and emit, for N envs on a device."""

from __future__ import annotations

import torch
from torchrl.data import Binary, Bounded, Composite, TensorSpec, Unbounded

from torchpark.aids.config import AidsConfig
from torchpark.aids.step import output_specs
from torchpark.config import ParkingConfig
from torchpark.sim.observation import observation_dim


def env_specs(num_envs: int, device: torch.device, config: ParkingConfig, aids: AidsConfig
              ) -> dict[str, TensorSpec]:
    """``EnvBase``'s specs by attribute name: the observation (N, D) float32 with success,
    collision (N, 1) bool, occupancy (N, 1) in [0, 1], the cost C (N, 1) and the aids'
    outputs; the action (N, 2) = (v m/s, delta rad) bounded by the vehicle's limits; the
    reward (N, 1); done, terminated, truncated (N, 1) bool."""
    n, dev, veh = num_envs, device, config.vehicle

    def flag() -> Binary:
        return Binary(n=1, shape=(n, 1), dtype=torch.bool, device=dev)

    def number(shape: tuple[int, ...]) -> Unbounded:
        return Unbounded(shape=shape, dtype=torch.float32, device=dev)

    limits = torch.tensor([veh.max_speed, veh.max_steer], device=dev).expand(n, 2)
    return {
        "observation_spec": Composite(
            observation=number((n, observation_dim(config))), success=flag(),
            collision=flag(),
            occupancy=Bounded(low=0.0, high=1.0, shape=(n, 1), dtype=torch.float32, device=dev),
            cost=number((n, 1)), **output_specs(aids, n, dev), shape=(n,), device=dev),
        "action_spec": Bounded(low=-limits, high=limits, shape=(n, 2), dtype=torch.float32,
                               device=dev),
        "reward_spec": number((n, 1)),
        "full_done_spec": Composite(done=flag(), terminated=flag(), truncated=flag(),
                                    shape=(n,), device=dev),
    }
