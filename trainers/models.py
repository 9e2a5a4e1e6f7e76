"""The paper's PPO networks: separate tanh MLPs for actor and critic, a state-independent
log-std (as Stable-Baselines3), and a TanhNormal policy inside the action bounds. Optionally
(``ModelConfig.state_dependent_std``) the actor outputs its scale too, so it can act with
less noise where precision pays (the last millimetres of parking)."""

from __future__ import annotations

import math

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
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


def orthogonal_init(mlp: nn.Module, output_gain: float) -> nn.Module:
    """Stable-Baselines3's initialisation: orthogonal weights with gain sqrt(2) in the hidden
    layers and ``output_gain`` in the last (0.01 for the policy, whose first actions are then
    near zero; 1 for the value), zero biases."""
    linears = [m for m in mlp.modules() if isinstance(m, nn.Linear)]
    for i, layer in enumerate(linears):
        nn.init.orthogonal_(layer.weight, output_gain if i == len(linears) - 1 else math.sqrt(2))
        nn.init.zeros_(layer.bias)
    return mlp


def make_ppo_models(obs_dim: int, action_spec: Bounded, cfg: ModelConfig
                    ) -> tuple[ProbabilisticActor, ValueOperator]:
    """Actor (NORMALISED -> action, sample_log_prob) and critic (NORMALISED -> state_value)."""
    action_dim = action_spec.shape[-1]
    low = action_spec.space.low.reshape(-1, action_dim)[0]
    high = action_spec.space.high.reshape(-1, action_dim)[0]
    if cfg.state_dependent_std:
        # scale = softplus(out + b) with b such that out = 0 gives exp(init_log_std).
        head = NormalParamExtractor(scale_mapping=f"biased_softplus_{math.exp(cfg.init_log_std)}",
                                    scale_lb=1e-4)
        out_features = 2 * action_dim
    else:
        head = StateIndependentScale(action_dim, cfg.init_log_std)
        out_features = action_dim
    policy = nn.Sequential(
        orthogonal_init(MLP(in_features=obs_dim, out_features=out_features,
                            num_cells=list(cfg.hidden), activation_class=nn.Tanh), 0.01),
        head,
    )
    actor = ProbabilisticActor(
        TensorDictModule(policy, in_keys=[NORMALISED], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"], spec=action_spec, distribution_class=TanhNormal,
        distribution_kwargs={"low": low, "high": high}, return_log_prob=True,
    )
    critic = ValueOperator(
        orthogonal_init(MLP(in_features=obs_dim, out_features=1, num_cells=list(cfg.hidden),
                            activation_class=nn.Tanh), 1.0),
        in_keys=[NORMALISED],
    )
    return actor, critic
