"""``ParkingEnv``: N parking lots as one batch-locked TorchRL environment.

The class is plumbing between torchrl and its parts: the agent's step (:mod:`torchpark.aids.step`:
the paper's, :mod:`torchpark.sim.step`, with the aids it is given around it), its rows
(:mod:`torchpark.rows`), a reset engine that draws new episodes and hands them to the rows
that reset (:mod:`torchpark.resets`: the host path, or the ring inside the step's graph), its
specs (:mod:`torchpark.specs`), snapshots (:mod:`torchpark.snapshots`) and pictures
(:mod:`torchpark.media`, imported on first use).

Actions (N, 2) = (v m/s, delta rad) are clamped to [-max_speed, max_speed] and
[-max_steer, max_steer]; float32 actions are taken as they are and float64 ones (what numpy
gives) rounded to float32, the env's precision; half precision (millimetres off after 100
steps, where success needs ~1 mm), integer and bool actions raise ValueError. Actions are
detached: no autograd graph enters the state. A row given a non-finite action takes (0, 0) and
stands still on either reset path (with ``validate_actions``, ValueError as well).

Outputs per step: observation (N, NAV_DIM + n_rays) float32 (:mod:`torchpark.sim.observation`);
reward, done, terminated, truncated, success, collision (N, 1); cost (N, 1) float32, the
paper's C that the success test compares (with held actions the lowest over the step's steps
of dt); occupancy (N, 1) float32, the occupancy the current lot was drawn with. With the brake
also braked (N, 1) bool (it stopped the last step of dt) and interventions (N, 1) int64 (steps
of dt it stopped or steered this episode); with the docking law docking_engaged (N, 1) bool
(it drives this episode); with ``observe_position`` position (N, 2) metres.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Sequence
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from torchpark._compat import post_step_mdp_hooks, step_mdp
from torchpark.aids.config import AidsConfig
from torchpark.aids.step import (
    AidedState,
    AidState,
    agent_step,
    aided_new_episodes,
    drivers,
    output_keys,
)
from torchpark.checks import (
    check_action,
    check_count,
    check_device,
    check_index,
    check_optional,
    check_pictures,
    check_row_mask,
    check_state,
    check_threshold,
)
from torchpark.compiling import check_compile_kwargs, compile_all, compiles
from torchpark.config import (
    SEED_LIMIT,
    ParkingConfig,
    check_flag,
    check_occupancy,
    check_seed,
)
from torchpark.memory import check_fits
from torchpark.resets import MAX_BLOCKS_AHEAD, EpisodeDraw, HostResets, RingResets
from torchpark.rows import Rows, check_rows, output_fields, row_bytes
from torchpark.sim.layout import LotLayout, build_layout
from torchpark.sim.observation import observation_dim, observe
from torchpark.sim.state import ParkingState
from torchpark.sim.step import put_rows_, take_rows
from torchpark.sim.world import World, build_world
from torchpark.snapshots import build_of, restore_snapshot, take_snapshot
from torchpark.specs import env_specs

if TYPE_CHECKING:  # Pillow, imported on the first picture
    from torchpark.media.overlay import Readout
    from torchpark.media.rendering import LotRenderer

__all__ = ["MAX_BLOCKS_AHEAD", "ParkingEnv", "check_device"]

# The reset's batch draw's working memory at its peak, in rows of state per env (323 bytes
# for the paper's lot): 115 eager, 12 compiled, measured as the growth of the process's peak
# RSS over a reset and three steps of N = 200,000 on a CPU.
_WORKING_ROWS = {False: 115, True: 12}


def _fixed(name: str, kind: object, doc: str, attribute: str | None = None) -> property:
    """A read-only attribute ``name`` of type ``kind`` (held in ``attribute``, a dotted path
    from the env; ``_name`` by default), set at construction: the step's functions were built
    from it, so a new value would be taken by some parts of the env and not others."""
    held = operator.attrgetter(attribute or "_" + name)

    def get(self: ParkingEnv) -> object:
        return held(self)

    get.__annotations__["return"] = kind  # the type the reference shows

    def refuse(self: ParkingEnv, value: object) -> None:
        raise AttributeError(f"ParkingEnv.{name} is fixed at construction (the step was built "
                             f"from it): build a new env instead")

    return property(get, refuse, doc=doc)


def take_reset(tensordict_: TensorDictBase, fresh: TensorDictBase,
               pad: Callable[[TensorDictBase], TensorDictBase] | None) -> None:
    """Put a reset into the next step's root ``tensordict_`` (in place) as torchrl's generic
    merge (``_update_during_reset``, a ``where`` per key) would. ``fresh`` is the env's reset
    output, which already holds for every row what that merge gives (the reset rows' new
    episodes, the other rows as the step left them, the end flags False, as they are in a
    row that did not end), so its keys replace those of ``tensordict_`` as they are. The
    other keys (the action, a policy's outputs) are replaced by ``pad`` of them, new tensors
    zeroed in the reset rows, as the merge makes them; ``pad`` None: left as they are."""
    others = tensordict_.exclude(*fresh.keys())
    tensordict_.update(fresh)
    if pad is not None and not others.is_empty():
        tensordict_.update(pad(others))


class ParkingEnv(EnvBase):
    """The paper's parking task for ``num_envs`` lots at once, every tensor on ``device``
    (actions and outputs: the module's docstring).

    Args:
        num_envs: number of lots (the batch size), >= 1.
        device: torch device of every tensor.
        seed: seed of the env's own ``torch.Generator``; None draws one from torch's global RNG.
        config: a :class:`ParkingConfig`; the paper's task by default.
        aids: an :class:`~torchpark.aids.config.AidsConfig` of agent-side aids (held actions,
            emergency brake, docking law, near-goal starts); None (default): the paper's env.
        compile_step: run the step and the batched draw of new episodes through
            ``torch.compile(fullgraph=True)``: several times faster on a CPU from a few hundred
            envs on; the first step then takes tens of seconds. Without a C++ compiler
            (:data:`~torchpark.compiling.compiler_found`) the env warns once and runs eager
            (:attr:`compiled`).
        compile_kwargs: passed to ``torch.compile``; in a mode that replays CUDA graphs each
            replay's outputs are copied out of the graphs' memory, which the next overwrites.
        validate_actions: raise ValueError on a non-finite action (its row stands still
            either way): on the host path after the step, the state left as it was; with
            ``reset_in_step`` at the ring's next read of its counters.
        reset_in_step: reset the rows a step ends inside the step's function in
            ``step_and_maybe_reset`` (rollouts, collectors), with no host read per step
            (:class:`~torchpark.resets.RingResets`). None (default): on CUDA, where that
            removes a synchronisation per step. Either path gives the same rollout for the
            same seed, under every setter.
        blocks_ahead: with ``reset_in_step``, the steps between two host reads, in [1, 256]:
            the ring holds ``blocks_ahead + 1`` blocks of N new episodes (~330 bytes each).
            An env too large for its device's free memory is refused before it allocates
            its rows (:class:`~torchpark.memory.TooLarge`, a ValueError).

    ``step`` before the first ``reset`` raises RuntimeError (the rows hold no lot yet).
    Setting :attr:`occupancy` applies to lots drawn at later resets (episodes drawn ahead at
    another occupancy are discarded, as they are on reseeding).
    """

    batch_locked = True

    def __init__(
        self,
        num_envs: int,
        *,
        device: torch.device | str = "cpu",
        seed: int | None = None,
        config: ParkingConfig | None = None,
        aids: AidsConfig | None = None,
        compile_step: bool = False,
        compile_kwargs: dict | None = None,
        validate_actions: bool = True,
        reset_in_step: bool | None = None,
        blocks_ahead: int = 8,
    ) -> None:
        n = check_count(num_envs, "num_envs", 1)
        compile_step = check_flag(compile_step, "compile_step")
        validate_actions = check_flag(validate_actions, "validate_actions")
        compile_kwargs = check_compile_kwargs(compile_kwargs)
        check_optional(config, ParkingConfig, "config")
        check_optional(aids, AidsConfig, "aids")
        device = check_device(device)
        reset_in_step = (device.type == "cuda" if reset_in_step is None
                         else check_flag(reset_in_step, "reset_in_step"))
        check_count(blocks_ahead, "blocks_ahead", 1, MAX_BLOCKS_AHEAD)
        super().__init__(device=device, batch_size=torch.Size([n]))
        self._num_envs = n
        self._config = cfg = config if config is not None else ParkingConfig()
        self._aids_config = aids
        self._agent = agent = aids if aids is not None else AidsConfig()  # none on: no aid
        self._layout = build_layout(cfg.lot, cfg.vehicle, self.device)
        # set_success_threshold changes the world's threshold in place; a compiled step
        # reads it at run time.
        self._world = build_world(self.layout, cfg)
        self._compiled = compile_step = compile_step and compiles("ParkingEnv(compile_step=True)")
        for name, spec in env_specs(n, self.device, cfg, agent).items():
            setattr(self, name, spec)
        engine = RingResets if reset_in_step else HostResets
        blocks, named = engine.ahead(blocks_ahead)  # the rows' blocks of N drawn ahead
        obstacles, dim = self._world.obstacles.cx.shape[0], self.obs_dim
        check_fits(n * row_bytes(obstacles, dim) * (1 + blocks + _WORKING_ROWS[compile_step]),
                   f"ParkingEnv(num_envs={n}{named})", self.device)
        self._rows = Rows.zeros(n, obstacles, dim, self.device)
        build = partial(compile_all, compile_kwargs=compile_kwargs) if compile_step else list
        new_episodes, = build([partial(aided_new_episodes, world=self._world, cfg=cfg)])
        draw = EpisodeDraw(n, cfg.occupancy, self.layout, cfg.lot, self._world,
                           agent.near_goal_starts, new_episodes,
                           torch.Generator(device=self.device))
        self._resets = engine(draw, agent_step(self._world, cfg, aids),
                              partial(output_fields, aid_keys=output_keys(agent),
                                      position=agent.observe_position),
                              build, validate_actions,
                              Rows.zeros(n * blocks, obstacles, dim, self.device))
        self._set_seed(seed)
        self._started = False  # no lot drawn yet: reset() first
        self._renderer: LotRenderer | None = None  # made on the first picture

    # ------------------------------------------------------------------ configuration
    num_envs = _fixed("num_envs", int, "The number of lots (the batch size).")
    config = _fixed("config", ParkingConfig, "The task's configuration.")
    layout = _fixed("layout", LotLayout, "The lot's geometry (its slots, walls and goal poses).")
    compiled = _fixed("compiled", bool, "Whether the step and the reset's draw are compiled.")
    reset_in_step = _fixed("reset_in_step", bool, "Whether ``step_and_maybe_reset`` resets "
                           "the rows a step ends inside the step's function.",
                           "_resets.reset_in_step")
    aids = _fixed("aids", AidsConfig | None, "The agent-side aids, None for the paper's env.",
                  "_aids_config")
    world = _fixed("world", World, "The constants every env shares, read-only, for analysis "
                   "and tests (obstacle boxes, goal poses, the success threshold).")

    @property
    def validate_actions(self) -> bool:
        """Whether a non-finite action raises (see the class's docstring); settable."""
        return self._resets.validate_actions

    @validate_actions.setter
    def validate_actions(self, value: bool) -> None:
        self._resets.validate_actions = check_flag(value, "validate_actions")

    @property
    def action_repeat(self) -> int:
        """Steps of dt one env step holds its action for (``aids.action_repeat``; 1 without
        aids): frames per env step."""
        return self._agent.action_repeat

    @property
    def occupancy(self) -> float:
        """Fraction in [0, 1] of the non-goal slots that hold a parked car in lots drawn from
        now on (exactly round_half_up(occupancy * (S - 1)) cars)."""
        return self._resets.draw.occupancy

    @occupancy.setter
    def occupancy(self, value: float) -> None:
        value = check_occupancy(value, "occupancy")
        if value != self.occupancy:
            self._resets.discard()  # lots drawn ahead at another occupancy: unused
        self._resets.draw.occupancy = value

    @property
    def success_threshold(self) -> float:
        """The success test's threshold on C (``config.reward.success_threshold`` at first).
        Reading it is a host sync on CUDA; set it with :meth:`set_success_threshold`."""
        return float(self._world.success_threshold)

    @success_threshold.setter
    def success_threshold(self, value: float) -> None:
        self.set_success_threshold(value)

    def set_success_threshold(self, value: float | torch.Tensor) -> None:
        """Set the success test's threshold on C from the next step on: a finite number > 0,
        or a 0-d float tensor holding one (copied; read back to be checked, on CUDA a
        synchronisation; one that requires grad is refused). With near-goal starts, which
        are drawn clear of the success test, the episodes drawn ahead are discarded."""
        number = check_threshold(value)
        self._resets.threshold_changed()
        self._world.success_threshold.fill_(number)

    @property
    def obs_dim(self) -> int:
        """The observation's width D (NAV_DIM + the rays)."""
        return observation_dim(self.config)

    # ------------------------------------------------------------------ seeding and state
    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            seed = int(torch.randint(0, SEED_LIMIT, (), dtype=torch.int64))
        seed = check_seed(seed, "seed")
        self._resets.discard()  # later lots come from the new seed
        self._resets.draw.generator.manual_seed(seed)

    @property
    def state(self) -> ParkingState:
        """A copy of the paper's per-env state (for analysis and tests; later steps and resets
        do not change it)."""
        return ParkingState(*(t.clone() for t in self._rows.state.sim))

    @property
    def aid_state(self) -> AidState:
        """A copy of the aids' per-env state (inert without aids, never braked, no
        intervention, the docking law never engaged)."""
        return AidState(*(t.clone() for t in self._rows.state.aids))

    def set_state(self, state: ParkingState, rows: torch.Tensor | None = None) -> TensorDictBase:
        """Put the rows ``rows`` ((N,) bool; default all) in the given paper state (a
        :class:`ParkingState` of N rows, e.g. ``env.state._replace(pose=...)``) at the start
        of an episode: the step counts and the aids' state of those rows are kept as given
        and cleared, respectively. Returns what a reset returns, observing the new state. For
        tests and analysis: nothing checks that the state is a valid start."""
        check_state(state, self._rows.state.sim)
        rows = check_row_mask(rows, self.num_envs, self.device)
        if not self._started and not bool(rows.all()):
            raise RuntimeError("ParkingEnv.set_state before reset must set every row (the "
                               "others hold no lot): call env.reset() first, or pass all rows")
        index = rows.nonzero()[:, 0]
        sim = take_rows(state, index)
        fresh = Rows(AidedState(sim, AidState.zeros(index.shape[0], self.device)),
                     *observe(sim, self._world, self.config))
        check_rows(fresh, self._world.goal_poses.shape[0], "state", "its observation")
        put_rows_(self._rows, index, fresh)
        self._started = True
        return self._resets.reset_output(self._rows)

    def snapshot(self) -> dict[str, torch.Tensor | float | bool | int | dict]:
        """Everything the env's future depends on, as plain tensors and numbers
        (:mod:`torchpark.snapshots`): :meth:`restore` continues exactly from it."""
        return take_snapshot(self._rows, self._resets, self._world, self._started,
                             build_of(self.num_envs, self.config, self._agent, self._resets))

    def restore(self, snapshot: dict) -> None:
        """Continue exactly from a :meth:`snapshot` of an env built the same way (same
        ``num_envs``, config, aids and reset path). All or nothing: every entry is checked
        before any is written, and a ValueError names the entry that does not fit (the env
        is then left as it was)."""
        self._rows, self._started = restore_snapshot(snapshot, self.snapshot(), self._resets,
                                                     self._world)

    def randomize_step_counts(self) -> None:
        """Set every env's step count to a uniform draw in [0, max_steps), from the env's
        generator, so that the current episodes end at spread-out times (for training: after
        a full reset all N would otherwise time out together, and a batch of a few steps from
        each env would be one time slice of synchronised episodes, again at every timeout)."""
        self._rows = self._resets.spread_steps(self._rows, self.config.max_steps)

    # ------------------------------------------------------------------ pictures
    def render(self, index: int = 0, readout: Readout | None = None) -> np.ndarray:
        """Picture of env ``index``'s lot now, (H, W, 3) uint8 (:mod:`torchpark.media`), with
        ``readout``'s numbers (:meth:`readout`) and, near the goal, its zoom."""
        return self.render_grid([check_index(index, self.num_envs)],
                                readouts=None if readout is None else [readout])

    def readout(self, index: int = 0, tensordict: TensorDictBase | None = None) -> Readout:
        """Env ``index``'s numbers for a picture's overlay, from its state now and ``step``'s
        output ``tensordict`` (:func:`torchpark.media.overlay.read_row`)."""
        index = check_index(index, self.num_envs)
        if not self._started:
            raise RuntimeError("ParkingEnv.readout before reset: call env.reset() first")
        from torchpark.media.overlay import read_row  # Pillow, on demand

        return read_row(self._rows.state.sim, self._rows.cost, self.success_threshold, index,
                        tensordict)

    def render_grid(self, indices: Sequence[int] | None = None, columns: int | None = None,
                    readouts: Sequence[Readout] | None = None) -> np.ndarray:
        """Pictures of several envs' lots (default: all) tiled row by row into one image,
        ``columns`` wide (an int in [1, len(indices)]; default about the square root), each
        with its driving layer and ``readouts``' numbers (one :meth:`readout` per index;
        :func:`~torchpark.media.rendering.picture_envs`)."""
        if not self._started:
            raise RuntimeError("ParkingEnv.render before reset: call env.reset() first")
        indices, columns = check_pictures(indices, columns, self.num_envs)
        from torchpark.media.rendering import LotRenderer, picture_envs  # Pillow, on demand

        if self._renderer is None:
            self._renderer = LotRenderer(self.layout, self.config)
        aid = take_rows(self._rows.state.aids, torch.tensor(indices, device=self.device))
        return picture_envs(self._renderer, self._rows.state.sim, self._rows.observation,
                            indices, columns, drivers(self._agent, aid), readouts)

    # ------------------------------------------------------------------ EnvBase hooks
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: object
               ) -> TensorDictBase:
        mask = None  # the first reset draws every row, whatever the mask
        if tensordict is not None and "_reset" in tensordict.keys() and self._started:
            mask = tensordict.get("_reset").reshape(self.num_envs).to(self.device, torch.bool)
        self._rows = self._resets.reset(self._rows, mask)
        self._started = True
        return self._resets.reset_output(self._rows)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if not self._started:
            raise RuntimeError("ParkingEnv.step before reset: call env.reset() first")
        action = check_action(tensordict.get("action", None), self.num_envs, self.device)
        self._rows, outputs = self._resets.step(self._rows, action)
        return outputs

    def _step_and_maybe_reset(self, tensordict: TensorDictBase
                              ) -> tuple[TensorDictBase, TensorDictBase]:
        """torchrl's step and reset of the ended rows (what ``env.step_and_maybe_reset``, the
        rollouts and the collectors call), the reset put in as torchrl's generic merge would
        (:func:`take_reset`): the same tensordicts as the generic path (tested), without its
        ``where`` per key."""
        if post_step_mdp_hooks(self) is not None:  # a hook of torchrl's: its generic path
            return super()._step_and_maybe_reset(tensordict)
        if tensordict.device != self.device:
            tensordict = tensordict.to(self.device)
        with self._resets.resetting() as reset:
            tensordict = self.step(tensordict)
        tensordict_ = step_mdp(self, tensordict)
        if reset.output is not None:  # None: the host path knows that no row ended
            take_reset(tensordict_, reset.output, reset.pad)
        return tensordict, tensordict_

    def step_resetting(self, step: Callable[[TensorDictBase], TensorDictBase],
                       tensordict: TensorDictBase) -> tuple[TensorDictBase, TensorDictBase]:
        """``step(tensordict)``, this env's ``step`` or that of a ``TransformedEnv`` around it,
        with the rows it ends reset inside this env's step. Returns its output (an ended
        row's last observation under "next") and what this env's reset returns for every
        row after it (the reset rows' new episodes, the other rows as they are, the end
        flags False)."""
        with self._resets.resetting() as reset:
            tensordict = step(tensordict)
        return tensordict, (reset.output if reset.output is not None
                            else self._resets.reset_output(self._rows))
