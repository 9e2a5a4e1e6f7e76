"""A trained agent in one call: :func:`load_agent` reads a checkpoint of the PPO recipe (or of
the distiller) and returns a :class:`TrainedAgent` that drives TorchRL and Gymnasium envs.

    from trainers.agent import load_agent

    agent = load_agent("results/policy_alone/checkpoint_best.pt")
    env = agent.make_env(num_envs=16, occupancy=0.5, seed=0)   # TorchRL, the agent's aids
    rollout = env.rollout(1000, agent.policy, break_when_all_done=True)

    gym_env = agent.gym_env(occupancy=0.5)                      # Gymnasium, the same agent
    obs, info = gym_env.reset(seed=0)
    action, _ = agent.predict(obs, info)

It lives with the recipe that wrote the checkpoint, as torchrl's own recipes keep their model
code beside their training script: a checkpoint holds the recipe's configuration and weights,
and only the recipe's code builds its networks and input transforms. ``trainers`` is a recipe
run from the repository's root (``python -m trainers.ppo``), not an installed package, so it
imports from there (or with the root on ``PYTHONPATH``); ``pip install`` puts only
``torchpark`` into site-packages, where a generic top-level name such as ``trainers`` would
collide with other projects'.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import gymnasium
import numpy as np
import torch
from tensordict import TensorDict
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import ProbabilisticActor

from torchpark import ENV_ID, AidsConfig, EpisodeFeature, ParkingConfig
from torchpark._compat import tree_map_only
from torchpark.config import check_flag
from trainers.checkpoint import load_trained, load_weights
from trainers.config import TrainConfig, check_device, env_configs
from trainers.features import feature_reads
from trainers.utils import build_models, make_eval_env


@dataclass(frozen=True)
class TrainedAgent:
    """A checkpoint's deterministic policy and what it needs around it.

    config: the run's configuration; actor: the policy network (a TorchRL
    ``ProbabilisticActor`` reading the normalised input; deterministic, the TanhNormal's
    mode, unless an exploration type says otherwise); obs_norm: its frozen input
    normalisation; trained_by: how it was made (COMPOSITION's ``policy``)."""

    config: TrainConfig
    actor: ProbabilisticActor
    obs_norm: dict
    trained_by: str

    @property
    def policy(self) -> ProbabilisticActor:
        """The policy for ``env.rollout`` on an env from :meth:`make_env`."""
        return self.actor

    @property
    def task(self) -> ParkingConfig:
        """The paper's task as the agent is evaluated on (training-only aids dropped)."""
        return env_configs(self.config, training=False)[0]

    @property
    def aids(self) -> AidsConfig | None:
        """The agent-side aids it drives with (brake, docking law, action repeat), None for a
        policy alone."""
        return env_configs(self.config, training=False)[1]

    def make_env(self, num_envs: int = 1, occupancy: float = 0.0, seed: int = 0
                 ) -> TransformedEnv:
        """``num_envs`` lots of the paper's task at ``occupancy`` with the agent's aids and
        input transforms (the evaluator's env: the same seed gives its lots)."""
        return make_eval_env(self.config, self.obs_norm, occupancy, num_envs, seed)

    def gym_env(self, **kwargs: Any) -> gymnasium.Env:
        """``gymnasium.make("torchpark/Parking-v0", ...)`` with the agent's task and aids;
        ``kwargs`` as that env's (``occupancy``, ``seed``, ``render_mode``, ...)."""
        return gymnasium.make(ENV_ID, config=self.task, aids=self.aids,
                              device=self.config.env.device, **kwargs)

    def predict(self, observation: np.ndarray, info: dict[str, Any] | None = None,
                deterministic: bool = True, state: np.ndarray | None = None,
                episode_start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """The action for a Gymnasium observation of :meth:`gym_env` ((23,), or (B, 23) with
        ``info`` arrays of B), as Stable-Baselines3's ``predict``: (action in that env's
        [-1, 1] Box, state). ``info``: the env's last info, which an agent trained with its
        position or brake flag in its input reads (ValueError naming what is missing).
        ``deterministic=False`` samples from the policy's distribution.

        ``state`` is None for an agent whose input is the observation of the moment. One with
        a feature that reads the episode so far (``torchpark.EpisodeFeature``: ``"gear"``,
        ``"scan_memory"`` in ``AgentConfig.features``) is a recurrent policy: pass back the
        state the last call returned ((S,) or (B, S): each such feature's state, in the
        input's order, e.g. the gear and its travel, m, then the remembered scans,
        flattened), None at an episode's first observation, and,
        as SB3 does, ``episode_start`` (B,) bool for the rows whose observation is a new
        episode's first (every row when ``state`` is None)."""
        given = np.asarray(observation)
        dim = self._inputs.base_env.obs_dim
        if given.dtype.kind not in "iuf":
            raise ValueError(f"observation must be a real array of shape ({dim},) or (B, {dim}), "
                             f"got dtype {given.dtype}")
        obs = torch.as_tensor(given.astype(np.float32))
        if obs.dim() not in (1, 2) or obs.shape[-1] != dim:
            raise ValueError(f"observation must have shape ({dim},) or (B, {dim}) (the "
                             f"paper's observation), got {tuple(obs.shape)}")
        if not bool(torch.isfinite(obs).all()):
            raise ValueError("observation must be finite (no NaN or inf)")
        deterministic = check_flag(deterministic, "deterministic")
        single = obs.dim() == 1
        batch = obs.reshape(-1, dim).to(self.config.env.device)
        td = TensorDict({"observation": batch}, batch_size=batch.shape[:1],
                        device=batch.device)
        for key in self._info_keys():
            if info is None or key not in info:
                raise ValueError(f"this agent reads info[{key!r}]: pass the info the env "
                                 f"returned with this observation (agent.gym_env() puts it "
                                 f"there)")
            value = torch.as_tensor(np.asarray(info[key]))
            width = self._inputs.base_env.observation_spec[key].shape[-1]
            if value.numel() != len(td) * width:
                raise ValueError(f"info[{key!r}] must hold one value per observation "
                                 f"({len(td)} x {width}), got shape {tuple(value.shape)}")
            td[key] = value.reshape(len(td), width).to(batch.device)
        transform = self._inputs.transform
        recurrent = self._recurrent
        if recurrent:
            going_on = self._resume(batch, state, episode_start)
            td["_reset"] = ~going_on[:, None]  # the rows that go on keep the state set here
        mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
        with torch.no_grad(), set_exploration_type(mode):
            # the input transforms as they observe a reset (none updates a statistic here)
            td = transform.inv(self.actor(transform._reset(td, td)))
        high = self._inputs.base_env.action_spec.space.high.reshape(-1, 2)[0]
        action = (td["action"] / high).clamp(-1.0, 1.0).cpu().numpy()
        if not recurrent:
            return (action[0] if single else action), None
        new_state = torch.cat([t.episode_state(batch) for t in recurrent], -1).cpu().numpy()
        return (action[0], new_state[0]) if single else (action, new_state)

    def _resume(self, batch: torch.Tensor, state: np.ndarray | None,
                episode_start: np.ndarray | None) -> torch.Tensor:
        """Sets the recurrent features' state for this observation (B, D): a new episode's
        rows start, the others go on from ``state`` (each feature's part of it, in the
        input's order). Returns the rows that go on, (B,) bool."""
        widths = [t.state_width for t in self._recurrent]
        b, width = batch.shape[0], sum(widths)
        going_on = torch.zeros(b, dtype=torch.bool, device=batch.device)
        before = torch.zeros(b, width, device=batch.device)
        if state is not None:
            before = torch.as_tensor(np.asarray(state, np.float32), device=batch.device)
            if before.numel() != width * b:
                raise ValueError(f"state must be the ({width},) or ({b}, {width}) array the "
                                 f"last predict returned (or None at an episode's first "
                                 f"observation), got shape {tuple(before.shape)}")
            before = before.reshape(b, width)
            going_on = torch.ones(b, dtype=torch.bool, device=batch.device)
            if episode_start is not None:
                start = torch.as_tensor(np.asarray(episode_start, bool), device=batch.device)
                if start.numel() != b:
                    raise ValueError(f"episode_start must hold one flag per observation "
                                     f"({b}), got shape {tuple(start.shape)}")
                going_on = ~start.reshape(b)
        for feature, part in zip(self._recurrent, before.split(widths, -1), strict=True):
            feature.resume(batch, part, going_on)
        return going_on

    @cached_property
    def _recurrent(self) -> list[EpisodeFeature]:
        """The input's features that read the episode so far (``EpisodeFeature``), in
        the input's order."""
        return [t for t in self._inputs.transform if isinstance(t, EpisodeFeature)]

    def _info_keys(self) -> tuple[str, ...]:
        """The env outputs besides the observation that the policy's input reads."""
        return feature_reads(self.config.agent)

    @cached_property
    def _inputs(self) -> TransformedEnv:
        """A one-lot env holding the agent's input transforms, for :meth:`predict`."""
        return self.make_env(1)


def load_agent(path: str, device: str | None = None) -> TrainedAgent:
    """The agent of the checkpoint at ``path`` (a ``trainers.ppo`` or ``trainers.distill``
    checkpoint; tensors and plain data only are read), on ``device`` (the training's by
    default); ValueError naming the file or the device that does not fit."""
    cfg, checkpoint = load_trained(path)
    if device is not None:
        cfg.env.device = device
    check_device(cfg.env.device, "device (the training's unless given)")
    checkpoint = tree_map_only(torch.Tensor, lambda t: t.to(cfg.env.device), checkpoint)
    actor, _ = build_models(cfg)
    load_weights(actor, checkpoint["actor"], path, "actor")
    trained_by = checkpoint.get("trained_by") or (
        f"PPO ({cfg.logger.exp_name} preset run), {checkpoint['frames']:,} frames")
    agent = TrainedAgent(cfg, actor.to(cfg.env.device), checkpoint["obs_norm"], trained_by)
    try:  # the input transforms with the saved normaliser, built now to check it
        _ = agent._inputs
    except ValueError as err:
        raise ValueError(f"checkpoint {str(path)!r}: {err}") from None
    return agent
