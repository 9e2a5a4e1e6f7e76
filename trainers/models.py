"""The paper's PPO networks: separate tanh MLPs for actor and critic, a state-independent
log-std (as Stable-Baselines3), and a TanhNormal policy inside the action bounds."""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

from trainers.config import ModelConfig

NORMALISED = "observation_norm"  # the normalised observation the networks read


class StateIndependentScale(nn.Module):
    """loc -> (loc, exp(log_std)) with one learned log-std per action dimension."""

    def __init__(self, action_dim: int, init_log_std: float) -> None:
        super().__init__()
        self.log_std = nn.Parameter(torch.full((action_dim,), init_log_std))

    def forward(self, loc: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return loc, self.log_std.exp().expand_as(loc)


def make_ppo_models(obs_dim: int, action_spec: Bounded, cfg: ModelConfig
                    ) -> tuple[ProbabilisticActor, ValueOperator]:
    """Actor (NORMALISED -> action, sample_log_prob) and critic (NORMALISED -> state_value)."""
    action_dim = action_spec.shape[-1]
    low = action_spec.space.low.reshape(-1, action_dim)[0]
    high = action_spec.space.high.reshape(-1, action_dim)[0]
    policy = nn.Sequential(
        MLP(in_features=obs_dim, out_features=action_dim, num_cells=list(cfg.hidden),
            activation_class=nn.Tanh),
        StateIndependentScale(action_dim, cfg.init_log_std),
    )
    actor = ProbabilisticActor(
        TensorDictModule(policy, in_keys=[NORMALISED], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"], spec=action_spec, distribution_class=TanhNormal,
        distribution_kwargs={"low": low, "high": high}, return_log_prob=True,
    )
    critic = ValueOperator(
        MLP(in_features=obs_dim, out_features=1, num_cells=list(cfg.hidden),
            activation_class=nn.Tanh),
        in_keys=[NORMALISED],
    )
    return actor, critic
