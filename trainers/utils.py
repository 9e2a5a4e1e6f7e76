"""What the PPO loop and the evaluator build, as in torchrl's recipes (``utils_mujoco.py``):
the envs (:func:`make_env`, :func:`make_eval_env`) and the networks (:func:`make_ppo_models`).

The networks are the paper's: separate tanh MLPs for actor and critic, a state-independent
log-std (as Stable-Baselines3), and a TanhNormal policy inside the action bounds. Optionally
(``ModelConfig.state_dependent_std``) the actor outputs its scale too, so it can act with
less noise where precision pays (the last millimetres of parking)."""

from __future__ import annotations

import math
import warnings

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.data import Bounded
from torchrl.envs import (
    Compose,
    InitTracker,
    RewardSum,
    StepCounter,
    Transform,
    TransformedEnv,
)
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

from torchpark import GearActionMap, OccupancyCurriculum, ParkingEnv, PowerActionMap
from torchpark.resets import MAX_BLOCKS_AHEAD
from torchpark.transforms.sync_free import SyncFreeEnv, SyncFreeRewardScaling, SyncFreeVecNorm
from trainers.config import ModelConfig, TrainConfig, env_configs
from trainers.features import feature_transforms
from trainers.heads import BinnedGearHead

NORMALISED = "observation_norm"  # the normalised observation the networks read

# torchrl warns that VecNormV2 (here SyncFreeVecNorm) on a batched env is experimental each
# time one is attached: ours is deliberate (one set of statistics over the batch,
# reduce_batch_dims=True, merged exactly across ranks and workers, tests/test_trainer.py and
# tests/test_distributed.py).
warnings.filterwarnings("ignore", category=UserWarning,
                        message="Support of .* for containers with non-empty batch-size")
# Stable-Baselines3's progress bar (the SB3 recipes' progress_bar=True) is tqdm's rich one,
# which tqdm calls experimental on every run.
warnings.filterwarnings("ignore", message="rich is experimental/alpha")


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
    if cfg.steer_bins:
        if action_dim != 5:
            raise ValueError(f"model.steer_bins needs the gear head's 5 actions "
                             f"(agent.gear_head), got {action_dim}")
        out_features = BinnedGearHead.out_features(cfg.steer_bins)
    body = orthogonal_init(MLP(in_features=obs_dim, out_features=out_features,
                               num_cells=list(cfg.hidden), activation_class=nn.Tanh), 0.01)
    if cfg.steer_bins:
        body = BinnedGearHead(body, cfg.steer_bins, cfg.state_dependent_std)
    policy = nn.Sequential(body, head)
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


def reset_exploration(actor: ProbabilisticActor, cfg: ModelConfig) -> None:
    """Set the std of a trained actor (from :func:`make_ppo_models`) back to
    ``exp(cfg.init_log_std)`` in every state, its mean untouched: the scale outputs' weights
    and biases zeroed (the state-dependent head maps 0 to that std), or the learned log-std
    filled."""
    policy = actor.module[0].module
    with torch.no_grad():
        if cfg.state_dependent_std:
            last = [m for m in policy[0].modules() if isinstance(m, nn.Linear)][-1]
            half = last.out_features // 2  # (loc, scale) halves, NormalParamExtractor's order
            last.weight[half:].zero_()
            last.bias[half:].zero_()
        else:
            policy[1].log_std.fill_(cfg.init_log_std)


def make_base_env(cfg: TrainConfig, training: bool, num_envs: int | None = None,
                  seed: int | None = None) -> ParkingEnv:
    """The run's ParkingEnv: its task and aids from :func:`trainers.config.env_configs`.
    Where it resets inside its step (CUDA), the host reads it back once per collector batch:
    ``blocks_ahead`` is the batch's env steps (at most the env's MAX_BLOCKS_AHEAD, 256: a
    longer batch reads every 256 steps)."""
    config, aids = env_configs(cfg, training)
    steps = cfg.collector.frames_per_batch // (cfg.env.num_envs * cfg.agent.aids.action_repeat)
    return ParkingEnv(cfg.env.num_envs if num_envs is None else num_envs,
                      device=cfg.env.device, seed=cfg.seed if seed is None else seed,
                      config=config, aids=aids, compile_step=cfg.env.compile_step and training,
                      reset_in_step=cfg.env.reset_in_step,
                      blocks_ahead=min(max(1, steps), MAX_BLOCKS_AHEAD))


def make_env(cfg: TrainConfig, num_envs: int | None = None, seed: int | None = None,
             replicas: int = 1) -> TransformedEnv:
    """The training env: ParkingEnv, episode statistics, the curriculum, observation norm
    (written to ``NORMALISED``). Its ``step_and_maybe_reset`` reads nothing back where the env
    resets inside its step (CUDA; ``torchpark.transforms.sync_free``).

    One of ``replicas`` copies stepping in lockstep (data-parallel ranks x collector workers,
    ``num_envs`` lots each): the curriculum counts the frames of all of them, and the
    normaliser's moving averages forget
    at the rate of the run's global batch (see :func:`policy_input`)."""
    base = make_base_env(cfg, training=True, num_envs=num_envs, seed=seed)
    return SyncFreeEnv(base, Compose(
        InitTracker(), StepCounter(), RewardSum(),
        OccupancyCurriculum(cfg.curriculum.levels, cfg.curriculum.frames_per_level, replicas),
        # After RewardSum: the logged episode reward stays in the paper's units.
        SyncFreeRewardScaling(loc=0.0, scale=cfg.loss.reward_scale),
        *policy_input(cfg, base, replicas),
    ))


def make_eval_env(cfg: TrainConfig, obs_norm: dict, occupancy: float, num_envs: int,
                  seed: int) -> TransformedEnv:
    """``num_envs`` lots at ``occupancy`` with the paper's starts, reward and success test and
    the agent's own aids, feeding the policy the trained (frozen) normalisation
    ``obs_norm`` (a checkpoint's)."""
    base = make_base_env(cfg, training=False, num_envs=num_envs, seed=seed)
    base.occupancy = occupancy
    inputs = policy_input(cfg, base)
    env = TransformedEnv(base, Compose(*inputs))
    norm = inputs[-1]
    try:
        norm.load_state_dict(obs_norm)
    except (RuntimeError, ValueError, KeyError, TypeError, AttributeError, IndexError) as err:
        text = str(err).strip().splitlines()
        raise ValueError(f"its obs_norm does not fit the input normaliser its config builds: "
                         f"{text[0] if text else type(err).__name__}") from None
    norm.freeze()
    return env


# VecNormV2's default: the weight of the past in its moving averages, per observation.
NORM_DECAY = 0.9999


def policy_input(cfg: TrainConfig, base: ParkingEnv, replicas: int = 1) -> list[Transform]:
    """The transforms between the env and the networks: the optional action maps (the power
    map onto the env's own action bounds, the gear head above it), then from the raw
    observation with the agent's features (``AgentConfig.features``, in their order:
    :data:`trainers.features.FEATURES`) to the networks' input ``NORMALISED`` (last).

    Normalised into its own key: the networks read it, while the raw observation stays in the
    data for evaluation and analysis (final position and heading errors). reduce_batch_dims:
    one set of statistics over all envs (VecNormV2's default keeps one per env).

    With ``replicas`` copies of the env, each forgets at ``NORM_DECAY ** replicas`` per
    observation: the moving averages are linear in the data, so the mean of the copies'
    statistics (``trainers.distributed.merge_normalisers``, after each batch) is what one
    normaliser would hold after the run's global batch.
    """
    transforms: list[Transform] = []
    agent = cfg.agent
    if agent.action_exponents is not None:
        high = base.action_spec.space.high.reshape(-1, base.action_spec.shape[-1])[0]
        transforms.append(PowerActionMap(high.cpu(), agent.action_exponents))
        if agent.gear_head:
            transforms.append(GearActionMap())
    features, source = feature_transforms(base, agent)
    return [*transforms, *features,
            SyncFreeVecNorm(in_keys=[source], out_keys=[NORMALISED],
                            decay=NORM_DECAY ** replicas, reduce_batch_dims=True)]


def build_models(cfg: TrainConfig) -> tuple[ProbabilisticActor, ValueOperator]:
    """The run's fresh actor and critic (:func:`make_ppo_models`), their input size and
    action bounds read from a one-lot env with the run's policy input."""
    probe = make_base_env(cfg, training=False, num_envs=1, seed=0)
    env = TransformedEnv(probe, Compose(*policy_input(cfg, probe)))
    return make_ppo_models(env.observation_spec[NORMALISED].shape[-1], env.action_spec,
                           cfg.model)
