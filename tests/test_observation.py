"""The paper's observation (torchpark.sim.observation): its layout and size."""

from __future__ import annotations

import torch
from torchrl.envs.utils import check_env_specs

from torchpark import LidarConfig, ParkingConfig, ParkingEnv
from torchpark.sim.observation import NAV_DIM, NAV_FIELDS


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
    assert torch.allclose(obs[:, 6], torch.sin(s.goal[:, 2]))
    assert ((obs[:, NAV_DIM:] >= 0) & (obs[:, NAV_DIM:] <= 1)).all()
    assert NAV_FIELDS == ("dx", "dy", "cos_psi", "sin_psi", "v", "cos_alpha", "sin_alpha")


def test_n_rays_option_changes_the_observation():
    env = ParkingEnv(2, seed=0, config=ParkingConfig(lidar=LidarConfig(n_rays=32)))
    assert env.reset()["observation"].shape == (2, 39)
    check_env_specs(ParkingEnv(2, seed=0, config=ParkingConfig(lidar=LidarConfig(n_rays=5))))
