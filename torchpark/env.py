"""``ParkingEnv``: N parking lots as one batch-locked TorchRL environment.

The class is plumbing: specs, seeding, action checks, the reset's mask, and the agent's step
and reset (:mod:`torchpark.aids.step`: the paper's, :mod:`torchpark.sim.step`, with the aids
it is given around it). It holds one state whatever the aids, an ``AidedState``: the paper's
state and the aids' beside it, inert when they are off. Pictures come from
:mod:`torchpark.media`, imported on first use.

A reset costs what it resets: the env draws N new episodes at a time (lots, start poses,
first observations: one batched, compiled call) and hands them out in order, each once, to
the rows that reset, writing those rows in place. The other rows are not touched, so a reset
of B rows costs a gather and a scatter of B rows, plus 1/N of a batch draw per row. It reads
the rows' count back (on CUDA a synchronisation, beside torchrl's ``done.any()``).

With ``reset_in_step`` (the default on CUDA) the reset of the rows a step ends happens in the
step's own graph instead (:mod:`torchpark.sim.ring`): episodes drawn ahead in a ring of blocks
of N, handed out by device counters that the host reads once every ``blocks_ahead`` steps. The
rows get the same episodes in the same order, with no data-dependent shape and no read-back
per step; each step writes every row (a select over the whole state), which costs more than
the host path's scatter of the reset rows on a CPU, where a read-back costs nothing.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence
from functools import partial

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

from torchpark._compat import post_step_mdp_hooks, step_mdp, tree_flatten
from torchpark.aids.brake import check_margin, steer_angles
from torchpark.aids.config import AidsConfig
from torchpark.aids.repeat import hold
from torchpark.aids.starts import draw_near
from torchpark.aids.step import (
    AidedState,
    AidState,
    agent_observation,
    agent_step,
    aided_new_episodes,
    output_keys,
    output_specs,
)
from torchpark.compiling import check_compile_kwargs, compile_all, compiler_found
from torchpark.config import (
    SEED_LIMIT,
    ParkingConfig,
    check_flag,
    check_occupancy,
    check_seed,
    is_integer,
    is_number,
)
from torchpark.memory import check_fits
from torchpark.sim.episodes import draw_lots
from torchpark.sim.layout import build_layout
from torchpark.sim.observation import observation_dim, observe
from torchpark.sim.ring import END_FLAGS, Counters, guarded_step, reset_rows, step_and_reset
from torchpark.sim.state import ParkingState
from torchpark.sim.step import put_rows_, take_rows
from torchpark.sim.world import World, build_world

# With reset_in_step, at most this many blocks of N episodes drawn ahead: a host read every
# 256 steps costs nothing measurable, and the first reset draws every block.
MAX_BLOCKS_AHEAD = 256
# The reset's batch draw's working memory at its peak, in rows of state per env (323 bytes
# for the paper's lot): 115 eager, 12 compiled, measured as the growth of the process's peak
# RSS over a reset and three steps of N = 200,000 on a CPU.
_WORKING_ROWS = {False: 115, True: 12}

def check_device(device: object, name: str = "device") -> None:
    """ValueError naming ``name`` unless ``device`` is a CPU or CUDA device this machine
    has."""
    try:
        parsed = torch.device(device)
    except (RuntimeError, TypeError):
        parsed = None
    if parsed is None or parsed.type not in ("cpu", "cuda"):
        raise ValueError(f"{name} must be a torch device such as 'cpu' or 'cuda:0', got "
                         f"{device!r}")
    if parsed.type == "cpu" and (parsed.index or 0) != 0:
        raise ValueError(f"{name} is {device!r}, but torch has one CPU device: 'cpu'")
    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if parsed.type == "cuda" and (parsed.index or 0) >= count:
        raise ValueError(f"{name} is {device!r}, but torch sees {count or 'no'} CUDA "
                         f"device(s) here")


def _fixed(name: str, doc: str, attribute: str | None = None) -> property:
    """A read-only attribute ``name`` (held in ``attribute``, ``_name`` by default), set at
    construction: the step's functions were built from it, so a new value would be taken by
    some parts of the env and not others."""
    held = attribute or "_" + name

    def get(self: ParkingEnv) -> object:
        return getattr(self, held)

    def refuse(self: ParkingEnv, value: object) -> None:
        raise AttributeError(f"ParkingEnv.{name} is fixed at construction (the step was built "
                             f"from it): build a new env instead")

    return property(get, refuse, doc=doc)


def output_fields(state: AidedState, observation: torch.Tensor, cost: torch.Tensor,
                  aid_keys: tuple[str, ...], position: bool) -> dict[str, torch.Tensor]:
    """The outputs read from a state (views, not copies): observation (N, D), cost (N, 1) and
    occupancy (N, 1) float32, the aids' keys ``aid_keys`` (N, 1), and with ``position`` the
    rear axle's position (N, 2) metres."""
    fields = {"observation": observation, "cost": cost[:, None],
              "occupancy": state.sim.occupancy[:, None],
              **{key: getattr(state.aids, key)[:, None] for key in aid_keys}}
    if position:
        fields["position"] = state.sim.pose[:, :2]
    return fields


def _first_difference(saved: object, ours: object, default: object = None, name: str = ""
                      ) -> str | None:
    """Where two nested dicts of plain data first differ, as ``"name=<saved> in the
    snapshot, <ours> here"``; None where they are equal. A key the snapshot lacks (a field
    added since it was taken) is read as its value in ``default`` (a nested dict of the
    same shape: the fields' defaults)."""
    if isinstance(saved, dict) and isinstance(ours, dict):
        default = default if isinstance(default, dict) else {}
        for key in sorted(set(saved) | set(ours), key=str):
            found = _first_difference(saved.get(key, default.get(key)), ours.get(key),
                                      default.get(key), f"{name}.{key}".lstrip("."))
            if found is not None:
                return found
        return None
    if saved != ours:
        return f"{name or 'build'}={saved!r} in the snapshot, {ours!r} here"
    return None


def _take_reset(tensordict_: TensorDictBase, fresh: TensorDictBase,
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
    """The paper's parking task for ``num_envs`` lots at once, every tensor on ``device``.

    Args:
        num_envs: number of lots (the batch size), >= 1.
        device: torch device of every tensor.
        seed: seed of the env's own ``torch.Generator``; None draws one from torch's global RNG.
        config: a :class:`ParkingConfig`; the paper's task by default.
        aids: an :class:`~torchpark.aids.config.AidsConfig` of agent-side aids (held actions,
            emergency brake, docking law, near-goal starts); None (default): the paper's env.
        compile_step: run the step and the batched draw of new episodes through
            ``torch.compile(fullgraph=True)``. Worth it from a few hundred envs on (several times
            faster on CPU); the first step then takes tens of seconds to compile.
            Without a C++ compiler (:func:`compiler_found`) the env warns once and runs
            eager; :attr:`compiled` says which.
        compile_kwargs: passed to ``torch.compile``. With a mode that replays CUDA graphs
            (``mode="reduce-overhead"``) the env copies each replay's outputs out of the
            graphs' memory (one foreach copy), since the next replay overwrites
            them.
        validate_actions: raise on non-finite actions. On either reset path a row given a
            non-finite action takes (0, 0) (it stands still: its pose never turns NaN). The
            test runs inside the step; on the host path its bool is read after the step (free
            on CPU, a synchronisation on CUDA) and the error leaves the state as it was. With
            ``reset_in_step`` it is read with the ring's counters instead, once every
            ``blocks_ahead`` hand-outs (a ``step_and_maybe_reset`` or a reset): the error
            comes at that read, the rows having stood still. False: no error, the rows
            stand still.
        reset_in_step: ``step_and_maybe_reset`` (rollouts, collectors) resets the rows a step
            ends inside the step's function, one graph from action to the next observation,
            with no host read-back per step (:mod:`torchpark.sim.ring`). None (default): on
            CUDA, where it removes a synchronisation per step; the CPU's host path is faster.
            Either gives the same rollout for the same seed, as long as nothing else draws
            from the env's generator in between (``randomize_step_counts``): this path draws
            its episodes up to ``blocks_ahead`` blocks earlier.
        blocks_ahead: with ``reset_in_step``, the steps between two host reads, in [1, 256];
            the env holds ``blocks_ahead + 1`` blocks of N new episodes (about 330 bytes
            each). An env that would not fit its device's free memory (its rows, those drawn
            ahead and the reset's working memory, estimated) is refused before it allocates
            them (:class:`~torchpark.memory.TooLarge`, a ValueError).

    Actions (N, 2) = (v m/s, delta rad) are clamped to [-max_speed, max_speed] and
    [-max_steer, max_steer] (documented behaviour); a non-finite action raises ValueError.
    float32 actions are taken as they are and float64 ones (what numpy gives) rounded to
    float32, the env's precision; half precision (float16, bfloat16: millimetres off after
    100 steps, where success needs ~1 mm), integer and bool actions raise ValueError. Actions
    are detached: no autograd graph enters the state. ``step`` before the first ``reset``
    raises RuntimeError (the state holds no lot yet).
    Outputs per step: observation (N, NAV_DIM + n_rays) float32 (``torchpark.sim.observation``);
    reward, done, terminated, truncated, success, collision (N, 1); cost (N, 1) float32, the
    paper's C that the success test compares (with held actions the lowest over the step's
    steps of dt); occupancy (N, 1) float32, the occupancy the current lot was drawn with.
    With the brake also braked (N, 1) bool (it stopped the last step of dt) and interventions
    (N, 1) int64 (steps of dt it stopped or steered this episode); with the docking law
    docking_engaged (N, 1) bool (it drives this episode). Setting :attr:`occupancy` applies
    to lots drawn at later resets (episodes drawn ahead at another occupancy are discarded,
    as they are on reseeding).
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
        if not is_integer(num_envs) or num_envs < 1:
            raise ValueError(f"num_envs must be an int >= 1, got {num_envs!r}")
        num_envs = int(num_envs)
        compile_step = check_flag(compile_step, "compile_step")
        validate_actions = check_flag(validate_actions, "validate_actions")
        compile_kwargs = check_compile_kwargs(compile_kwargs)
        if config is not None and not isinstance(config, ParkingConfig):
            raise TypeError(f"config must be a ParkingConfig, got {type(config).__name__}")
        if aids is not None and not isinstance(aids, AidsConfig):
            raise TypeError(f"aids must be an AidsConfig or None, got {type(aids).__name__}")
        check_device(device)
        device = torch.device(device)
        device = torch.device("cpu") if device.type == "cpu" else device  # "cpu:0" is "cpu"
        reset_in_step = (torch.device(device).type == "cuda" if reset_in_step is None
                         else check_flag(reset_in_step, "reset_in_step"))
        if not is_integer(blocks_ahead) or not 1 <= blocks_ahead <= MAX_BLOCKS_AHEAD:
            raise ValueError(f"blocks_ahead must be an int in [1, {MAX_BLOCKS_AHEAD}], got "
                             f"{blocks_ahead!r}")
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self._num_envs = num_envs
        self._config = cfg = config if config is not None else ParkingConfig()
        self._aids_config = aids
        # The aids' settings the step and reset read: none on, when there is no aid.
        self._agent = agent = aids if aids is not None else AidsConfig()
        self.validate_actions = validate_actions
        self._occupancy = cfg.occupancy
        self._layout = build_layout(cfg.lot, cfg.vehicle, self.device)
        # set_success_threshold changes the world's threshold in place;
        # a compiled step reads it at run time.
        self._world = build_world(self.layout, cfg)
        if agent.brake is not None:
            check_margin(agent.brake.margin, self._world, cfg.vehicle)
        angles = steer_angles(cfg, agent.brake, self.device) if agent.brake is not None \
            else torch.empty(0, device=self.device)
        step = agent_step(self._world, angles, cfg, aids)
        reset = partial(aided_new_episodes, world=self._world, cfg=cfg)
        # A held action's steps of dt are one function (one graph when compiled).
        step = hold(step, self.action_repeat,
                    partial(agent_observation, world=self._world, cfg=cfg))
        if compile_step and not compiler_found():
            warnings.warn("ParkingEnv(compile_step=True) runs eager: torch.compile needs a C++ "
                          "compiler and none was found (install g++ or set CXX)",
                          RuntimeWarning, stacklevel=2)
            compile_step = False
        self._compiled = compile_step  # whether the step and the reset's draw are compiled
        self._fields = partial(output_fields, aid_keys=output_keys(agent),
                               position=agent.observe_position)
        functions = [step, reset, partial(step_and_reset, step, self._fields),
                     partial(reset_rows), partial(guarded_step, step)]
        if compile_step:
            functions = compile_all(functions, compile_kwargs)
        # The step; the reset's work: N new episodes at a time (lots, start poses, first
        # observations), drawn ahead and handed out in order, each once, to the rows that
        # reset; with reset_in_step, the step and that reset as one function, the reset of a
        # mask's rows from the ring, and the step alone with its action check on the device.
        (self._step_fn, self._new_episodes, self._step_reset_fn, self._reset_fn,
         self._guarded_fn) = functions
        self._reset_in_step = reset_in_step
        self._make_specs()
        self._blocks = blocks_ahead + 1 if reset_in_step else 0
        self._check_size()
        self._state, self._observation, self._cost = self._zeros()
        # The host path's episodes drawn ahead (a state of N rows, observations, costs);
        # the first `_ahead_used` of them are handed out.
        self._ahead, self._ahead_used = self._zeros(), num_envs
        # reset_in_step's ring of `_blocks` blocks of N episodes and its device counters:
        # block 0 stands for no block (all used); the host has drawn blocks [0, _drawn),
        # last read block `_known` and let `_unread` hand-outs run since.
        self._ring = self._zeros(self._blocks * num_envs) if reset_in_step else None
        self._counters = Counters(torch.tensor(0, device=self.device),
                                  torch.tensor(num_envs, device=self.device))
        self._bad_action = torch.tensor(False, device=self.device)  # read with the counters
        self._no_bad_action = torch.tensor(False, device=self.device)  # the host path's start
        self._drawn, self._known, self._unread = 1, 0, 0
        self._after_reset: TensorDictBase | None = None  # what the last step's reset returns
        self._resetting = False  # _step is called from _step_and_reset
        self._generator = torch.Generator(device=self.device)
        # reset_in_step: the generator's state before each ring block was drawn (by slot)
        self._ring_rng = [self._generator.get_state()] * self._blocks
        self._set_seed(seed)
        self._started = False  # no lot drawn yet: reset() first
        self._renderer = None  # a media.rendering.LotRenderer, made on the first picture

    # ------------------------------------------------------------------ configuration
    num_envs = _fixed("num_envs", "The number of lots (the batch size).")
    config = _fixed("config", "The task's :class:`ParkingConfig`.")
    layout = _fixed("layout", "The lot's geometry (:func:`torchpark.sim.layout.build_layout`).")
    compiled = _fixed("compiled", "Whether the step and the reset's draw are compiled.")
    reset_in_step = _fixed("reset_in_step", "Whether ``step_and_maybe_reset`` resets the "
                           "rows a step ends inside the step's function.")

    aids = _fixed("aids", "The agent-side aids' :class:`~torchpark.aids.config.AidsConfig` "
                  "(None: the paper's env).", "_aids_config")

    @property
    def validate_actions(self) -> bool:
        """Whether a non-finite action raises (see the class's docstring); settable."""
        return self._validate_actions

    @validate_actions.setter
    def validate_actions(self, value: bool) -> None:
        self._validate_actions = check_flag(value, "validate_actions")

    @property
    def action_repeat(self) -> int:
        """Steps of dt one env step holds its action for (``aids.action_repeat``; 1 without
        aids): frames per env step."""
        return self._agent.action_repeat

    @property
    def occupancy(self) -> float:
        """Fraction in [0, 1] of the non-goal slots that hold a parked car in lots drawn from
        now on (exactly round_half_up(occupancy * (S - 1)) cars)."""
        return self._occupancy

    @occupancy.setter
    def occupancy(self, value: float) -> None:
        value = check_occupancy(value, "occupancy")
        if value != self._occupancy:
            self._discard_ahead()  # lots drawn ahead at another occupancy: unused
        self._occupancy = value

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
        or a 0-d float tensor holding one (copied; its value is read back to be checked, on
        CUDA a synchronisation; one that requires grad is refused). With near-goal starts,
        which are drawn clear of the success test, the episodes drawn ahead are
        discarded."""
        if isinstance(value, torch.Tensor):
            if value.dim() != 0 or not value.is_floating_point() or value.requires_grad:
                raise ValueError(f"success_threshold must be a 0-d float tensor that does not "
                                 f"require grad, got shape {tuple(value.shape)} {value.dtype}"
                                 f"{' requiring grad' if value.requires_grad else ''}")
            number = float(value)
        else:
            number = value
        if not is_number(number) or not math.isfinite(number) or number <= 0:
            raise ValueError(f"success_threshold must be a finite float > 0, got {value!r}")
        if self._agent.near_goal_starts is not None:
            self._discard_ahead()
        self._world.success_threshold.fill_(float(number))

    @property
    def obs_dim(self) -> int:
        return observation_dim(self.config)

    def _make_specs(self) -> None:
        n, dev, veh = self.num_envs, self.device, self.config.vehicle

        def flag() -> Binary:
            return Binary(n=1, shape=(n, 1), dtype=torch.bool, device=dev)

        self.observation_spec = Composite(
            observation=Unbounded(shape=(n, self.obs_dim), dtype=torch.float32, device=dev),
            success=flag(),
            collision=flag(),
            occupancy=Bounded(low=0.0, high=1.0, shape=(n, 1), dtype=torch.float32, device=dev),
            cost=Unbounded(shape=(n, 1), dtype=torch.float32, device=dev),
            **output_specs(self._agent, n, dev),
            shape=(n,),
            device=dev,
        )
        self.action_spec = Bounded(
            low=torch.tensor([-veh.max_speed, -veh.max_steer], device=dev).expand(n, 2),
            high=torch.tensor([veh.max_speed, veh.max_steer], device=dev).expand(n, 2),
            shape=(n, 2), dtype=torch.float32, device=dev,
        )
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32, device=dev)
        self.full_done_spec = Composite(
            done=flag(), terminated=flag(), truncated=flag(), shape=(n,), device=dev
        )

    # ------------------------------------------------------------------ seeding and state
    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            seed = int(torch.randint(0, SEED_LIMIT, (), dtype=torch.int64))
        seed = check_seed(seed, "seed")
        self._discard_ahead()  # later lots come from the new seed
        self._generator.manual_seed(seed)

    def _discard_ahead(self) -> None:
        """Hand out none of the episodes drawn so far: later resets draw new ones (from the
        generator, at the occupancy, against the success threshold of that time). With
        reset_in_step, one read of the counters, and the generator put back to where it was
        before the blocks drawn ahead of the current one: the host path, which draws a block
        only when it needs one, has drawn no further, so both draw the same lots next."""
        self._ahead_used = self.num_envs
        if self.reset_in_step:
            block = int(self._counters.block)
            if self._drawn > block + 1:
                self._generator.set_state(self._ring_rng[(block + 1) % self._blocks])
            self._counters.used.fill_(self.num_envs)
            self._drawn, self._known, self._unread = block + 1, block, 0

    def _ring_ready(self) -> None:
        """Before a hand-out from the ring: make sure the block it may move to is drawn.
        Where the host can no longer tell, it reads the counters (and the non-finite action
        flag) back, once, and draws the blocks spent since, in order."""
        if self._known + self._unread + 2 <= self._drawn:
            return
        block, bad = torch.stack((self._counters.block, self._bad_action.long())).tolist()
        if bad and self.validate_actions:
            self._bad_action.fill_(False)
            raise ValueError("action must be finite (no NaN or inf); a non-finite value "
                             "reached a step since the env's last read of its counters (its "
                             "rows stood still)")
        self._known, self._unread = block, 0
        n = self.num_envs
        while self._drawn < block + self._blocks:
            slot = self._drawn % self._blocks
            self._ring_rng[slot] = self._generator.get_state()  # for _discard_ahead
            put_rows_(self._ring, torch.arange(slot * n, (slot + 1) * n, device=self.device),
                      self._draw_episodes())
            self._drawn += 1

    @property
    def world(self) -> World:
        """The constants every env shares (obstacle boxes, goal poses, the success threshold):
        read-only, for analysis and tests."""
        return self._world

    @property
    def state(self) -> ParkingState:
        """A copy of the paper's per-env state (for analysis and tests; later steps and resets
        do not change it)."""
        return ParkingState(*(t.clone() for t in self._sim))

    @property
    def aid_state(self) -> AidState:
        """A copy of the aids' per-env state (inert without aids: never braked, no
        intervention, the docking law never engaged)."""
        return AidState(*(t.clone() for t in self._aids))

    @property
    def _sim(self) -> ParkingState:
        """The paper's state, the env's own tensors (a reset writes its rows in place)."""
        return self._state.sim

    @property
    def _aids(self) -> AidState:
        return self._state.aids

    def _write_rows(self, index: torch.Tensor, state: tuple, observation: torch.Tensor,
                    cost: torch.Tensor) -> None:
        """Write B new rows (an ``AidedState``, observation (B, D), cost (B,)) into
        the rows ``index`` (B,) int64, in place: the other rows are not touched."""
        put_rows_(self._state, index, state)
        self._observation.index_copy_(0, index, observation)
        self._cost.index_copy_(0, index, cost)

    def set_state(self, state: ParkingState, rows: torch.Tensor | None = None) -> TensorDictBase:
        """Put the rows ``rows`` ((N,) bool; default all) in the given paper state (a
        :class:`ParkingState` of N rows, e.g. ``env.state._replace(pose=...)``) at the start
        of an episode: the step counts and the aids' state of those rows are kept as given
        and cleared, respectively. Returns what a reset returns, observing the new state. For
        tests and analysis: nothing checks that the state is a valid start."""
        if not isinstance(state, ParkingState):
            raise TypeError(f"state must be a ParkingState, got {type(state).__name__}")
        for name, new, old in zip(ParkingState._fields, state, self._sim, strict=True):
            if not isinstance(new, torch.Tensor) or new.shape != old.shape \
                    or new.dtype != old.dtype or new.device != old.device:
                raise ValueError(f"state.{name} must be a {old.dtype} tensor of shape "
                                 f"{tuple(old.shape)} on {old.device}, got {new!r}")
        if rows is None:
            rows = torch.ones(self.num_envs, dtype=torch.bool, device=self.device)
        elif not isinstance(rows, torch.Tensor) or rows.dtype != torch.bool \
                or rows.numel() != self.num_envs:
            raise ValueError(f"rows must be a bool tensor of {self.num_envs} elements (one per "
                             f"env), got {rows!r}")
        rows = rows.to(self.device).reshape(self.num_envs)
        if not self._started and not bool(rows.all()):
            raise RuntimeError("ParkingEnv.set_state before reset must set every row (the "
                               "others hold no lot): call env.reset() first, or pass all rows")
        index = rows.nonzero()[:, 0]
        sim = take_rows(state, index)
        fresh = AidedState(sim, AidState.zeros(index.shape[0], self.device))
        self._check_state(fresh, "state")
        observation, cost = observe(sim, self._world, self.config)
        self._write_rows(index, fresh, observation, cost)
        self._started = True
        return self._reset_output()

    def _check_state(self, state: AidedState, name: str) -> None:
        """ValueError naming ``name.field`` where a state (rows [B, ...])
        holds what no episode can: a non-finite pose, speed or goal, a goal slot outside the
        lot's, a presence other than 0 or 1, a negative step or intervention count, an
        occupancy outside [0, 1]. One read-back: for set_state and restore, not the step."""
        sim, aid = state
        slots = self._world.goal_poses.shape[0]
        checks = [
            ("pose", torch.isfinite(sim.pose).all(), "finite"),
            ("speed", torch.isfinite(sim.speed).all(), "finite"),
            ("goal", torch.isfinite(sim.goal).all(), "finite"),
            ("goal_slot", ((sim.goal_slot >= 0) & (sim.goal_slot < slots)).all(),
             f"a slot index in [0, {slots})"),
            ("present", ((sim.present == 0) | (sim.present == 1)).all(), "0 or 1"),
            ("steps", (sim.steps >= 0).all(), ">= 0"),
            ("occupancy", ((sim.occupancy >= 0) & (sim.occupancy <= 1)).all(), "in [0, 1]"),
            ("aids.interventions", (aid.interventions >= 0).all(), ">= 0"),
        ]
        held = torch.stack([ok for _, ok, _ in checks]).tolist()  # the one read-back
        for (field, _, allowed), fine in zip(checks, held, strict=True):
            if not fine:
                raise ValueError(f"{name}.{field} must be {allowed} in every row")

    def _check_size(self) -> None:
        """:class:`~torchpark.memory.TooLarge` before anything of N rows is allocated, where
        the env would not fit its device: N rows of state (and their observations) for the
        lots, as many drawn ahead (the ring's blocks with reset_in_step), and the reset's
        batch draw's working memory at its peak (_WORKING_ROWS)."""
        row = sum(t.numel() * t.element_size() for t in tree_flatten(self._zeros(1))[0])
        rows = 2 + self._blocks + _WORKING_ROWS[self.compiled]
        check_fits(self.num_envs * row * rows,
                   f"ParkingEnv(num_envs={self.num_envs}"
                   + (f", blocks_ahead={self._blocks - 1})" if self._blocks else ")"),
                   self.device)

    def _zeros(self, rows: int | None = None) -> tuple[AidedState, torch.Tensor, torch.Tensor]:
        """A state of ``rows`` rows (default N) holding no lot, with its observation and
        cost: zeros."""
        n, m = rows or self.num_envs, self._world.obstacles.cx.shape[0]
        return (AidedState(ParkingState.zeros(n, m, self.device), AidState.zeros(n, self.device)),
                torch.zeros(n, self.obs_dim, device=self.device),
                torch.zeros(n, device=self.device))

    def _flat(self, state: AidedState, observation: torch.Tensor, cost: torch.Tensor,
              prefix: str = "") -> dict[str, torch.Tensor]:
        """A state with its observation and cost as named copies."""
        sim, aid = state
        fields = {f"{prefix}state.{k}": v for k, v in zip(ParkingState._fields, sim,
                                                           strict=True)}
        fields |= {f"{prefix}aids.{k}": v for k, v in zip(AidState._fields, aid, strict=True)}
        fields |= {f"{prefix}observation": observation, f"{prefix}cost": cost}
        return {k: v.clone() for k, v in fields.items()}

    def _unflat(self, fields: dict, prefix: str = "") -> tuple:
        """The inverse of :meth:`_flat`: (state, observation, cost), copied to the device (the
        env writes its tensors in place, never the caller's)."""
        def get(name: str) -> torch.Tensor:
            return fields[prefix + name].to(self.device, copy=True)

        state = AidedState(ParkingState(*(get(f"state.{k}") for k in ParkingState._fields)),
                           AidState(*(get(f"aids.{k}") for k in AidState._fields)))
        return state, get("observation"), get("cost")

    def _build(self) -> dict:
        """How the env was built (what its state's meaning depends on), as plain data: the
        number of lots, the task's config and the aids'."""
        return {"num_envs": self.num_envs, "config": dataclasses.asdict(self.config),
                "aids": dataclasses.asdict(self._agent), "reset_in_step": self.reset_in_step,
                "ring_blocks": self._blocks}

    def snapshot(self) -> dict[str, torch.Tensor | float | bool | int | dict]:
        """Everything the env's future depends on, as plain tensors and numbers (safe for
        ``torch.save`` and ``torch.load(weights_only=True)``): every lot's state (and the
        aids'), the last observation and cost, the episodes drawn ahead and how many of them
        are handed out (with ``reset_in_step``, the ring, its counters and the blocks
        drawn), the random generator, the occupancy of later lots, the success threshold, and
        how the env was built (``build``: its size, configs and reset path, so that an env
        built otherwise refuses it). :meth:`restore` continues exactly from it."""
        if self.reset_in_step:
            ahead = {**self._flat(*self._ring, prefix="ring."), "ring_drawn": self._drawn,
                     "ring_counters": torch.stack((*self._counters, self._bad_action.long())),
                     "ring_generators": torch.stack(self._ring_rng)}
        else:
            ahead = {**self._flat(*self._ahead, prefix="ahead."), "ahead_used": self._ahead_used}
        return {**self._flat(self._state, self._observation, self._cost), **ahead,
                "generator": self._generator.get_state(), "occupancy": self._occupancy,
                "success_threshold": self._world.success_threshold.clone(),
                "started": self._started, "build": self._build()}

    def restore(self, snapshot: dict) -> None:
        """Continue exactly from a :meth:`snapshot` of an env built the same way (same
        ``num_envs``, config and aids). All or nothing: every entry is checked before any is
        written, and a ValueError names the entry that does not fit (the env is then left as
        it was)."""
        if not isinstance(snapshot, dict):
            raise TypeError(f"snapshot must be a dict from ParkingEnv.snapshot, got "
                            f"{type(snapshot).__name__}")
        expected = self.snapshot()
        # Snapshots from before the reset path was a choice are of the host path.
        defaults = {"config": dataclasses.asdict(ParkingConfig()),
                    "aids": dataclasses.asdict(AidsConfig()), "reset_in_step": False,
                    "ring_blocks": 0}
        differs = _first_difference(snapshot.get("build"), expected["build"], defaults)
        if differs is not None:
            raise ValueError(f"snapshot['build'] is of an env built otherwise: {differs}")
        missing = sorted(set(expected) - set(snapshot))
        if missing or set(snapshot) - set(expected):
            raise ValueError(f"snapshot must hold exactly {sorted(expected)}; missing "
                             f"{missing}, extra {sorted(set(snapshot) - set(expected))}")
        for key, ours in expected.items():
            theirs = snapshot[key]
            if isinstance(ours, torch.Tensor) and (
                    not isinstance(theirs, torch.Tensor) or theirs.shape != ours.shape
                    or theirs.dtype != ours.dtype):
                raise ValueError(f"snapshot[{key!r}] must be a {ours.dtype} tensor of shape "
                                 f"{tuple(ours.shape)}, got {theirs!r}")
        if self.reset_in_step:
            block, used, bad = snapshot["ring_counters"].tolist()
            drawn = snapshot["ring_drawn"]
            if not (is_integer(drawn) and 0 <= block < drawn <= block + self._blocks
                    and 0 <= used <= self.num_envs and bad in (0, 1)):
                raise ValueError(f"snapshot['ring_counters'] (block, used, bad action) and "
                                 f"['ring_drawn'] must satisfy 0 <= block < drawn <= block + "
                                 f"{self._blocks}, used in [0, {self.num_envs}], bad 0 or 1; "
                                 f"got {(block, used, bad)}, {drawn!r}")
        else:
            used = snapshot["ahead_used"]
            if not is_integer(used) or not 0 <= used <= self.num_envs:
                raise ValueError(f"snapshot['ahead_used'] must be an int in "
                                 f"[0, {self.num_envs}], got {used!r}")
        occupancy = check_occupancy(snapshot["occupancy"], "snapshot['occupancy']")
        started = check_flag(snapshot["started"], "snapshot['started']")
        threshold = snapshot["success_threshold"]
        if not bool(torch.isfinite(threshold) & (threshold > 0)):
            raise ValueError(f"snapshot['success_threshold'] must be a finite number > 0, got "
                             f"{threshold!r}")
        generators = [("generator", snapshot["generator"])] + [
            (f"ring_generators'][{i}", state.clone())  # set_state reads whole tensors
            for i, state in enumerate(snapshot.get("ring_generators", ()))]
        for name, state in generators:
            try:  # a generator state of the right size may still be no valid one
                torch.Generator(device=self.device).set_state(state)
            except RuntimeError as err:
                raise ValueError(f"snapshot['{name}'] is not a state of this device's random "
                                 f"generator: {str(err).splitlines()[0]}") from None
        pool = "ring." if self.reset_in_step else "ahead."
        current, ahead = self._unflat(snapshot), self._unflat(snapshot, pool)
        for (state, observation, cost), prefix in ((current, ""), (ahead, pool)):
            self._check_state(state, f"snapshot['{prefix}state']")
            if not bool(torch.isfinite(observation).all() & torch.isfinite(cost).all()):
                raise ValueError(f"snapshot['{prefix}observation'] and ['{prefix}cost'] must "
                                 f"be finite")
        # Everything fits: written from here on, nothing can fail half-way. The occupancy
        # and the threshold first: what they discard is replaced below.
        self.occupancy = occupancy
        self.set_success_threshold(threshold)
        self._state, self._observation, self._cost = current
        self._generator.set_state(snapshot["generator"])
        self._started = started
        if self.reset_in_step:
            self._ring = ahead
            self._ring_rng = [state.clone() for state in snapshot["ring_generators"]]
            counters = snapshot["ring_counters"].to(self.device, copy=True)
            self._counters, self._bad_action = Counters(counters[0], counters[1]), counters[2] > 0
            self._drawn, self._known, self._unread = int(drawn), int(block), 0
        else:
            self._ahead, self._ahead_used = ahead, int(used)

    def randomize_step_counts(self) -> None:
        """Set every env's step count to a uniform draw in [0, max_steps), from the env's
        generator, so the current episodes end at spread-out times.

        For training: after a full reset all N episodes would otherwise time out together,
        and a batch of a few steps from each env would be one time slice of synchronised
        episodes (e.g. only their first steps), again at every timeout.
        """
        steps = torch.randint(self.config.max_steps, (self.num_envs,),
                              generator=self._generator, device=self.device)
        self._state = self._state._replace(sim=self._sim._replace(steps=steps))

    # ------------------------------------------------------------------ pictures
    def render(self, index: int = 0) -> np.ndarray:
        """Picture of env ``index``'s lot now, (H, W, 3) uint8 (see
        :mod:`torchpark.media.rendering`)."""
        if not is_integer(index) or not 0 <= index < self.num_envs:
            raise IndexError(f"index must be an int in [0, {self.num_envs - 1}], got {index!r}")
        return self.render_grid([int(index)])

    def render_grid(self, indices: Sequence[int] | None = None, columns: int | None = None
                    ) -> np.ndarray:
        """Pictures of several envs' lots (default: all) tiled row by row into one image,
        ``columns`` wide (an int in [1, len(indices)]; default about the square root). A grid
        larger than the host's free memory is refused before it is drawn."""
        if not self._started:
            raise RuntimeError("ParkingEnv.render before reset: call env.reset() first")
        if indices is not None and (isinstance(indices, (str, bytes))
                                    or not isinstance(indices, (Sequence, np.ndarray))):
            raise TypeError(f"indices must be a sequence of env indices (ints in [0, "
                            f"{self.num_envs - 1}]) or None, got {indices!r}")
        if indices is not None and not all(is_integer(i) for i in indices):
            raise IndexError(f"indices must be ints in [0, {self.num_envs - 1}], got "
                             f"{list(indices)}")
        indices = list(range(self.num_envs)) if indices is None else [int(i) for i in indices]
        bad = [i for i in indices if not 0 <= i < self.num_envs]
        if bad or not indices:
            raise IndexError(f"indices must be non-empty ints in [0, {self.num_envs - 1}], "
                             f"got {bad or indices}")
        if columns is not None and not (is_integer(columns) and 1 <= columns <= len(indices)):
            raise ValueError(f"columns must be an int in [1, {len(indices)}] (the pictures' "
                             f"count) or None, got {columns!r}")
        from torchpark.media.rendering import LotRenderer, picture_envs  # Pillow, on demand

        if self._renderer is None:
            self._renderer = LotRenderer(self.layout, self.config)
        width, height = self._renderer.size
        check_fits(2 * len(indices) * width * height * 3,  # the pictures and their grid
                   f"render_grid of {len(indices)} pictures", torch.device("cpu"))
        return picture_envs(self._renderer, self._sim, self._observation, indices,
                            None if columns is None else int(columns), self._drivers(indices))

    def _drivers(self, indices: list[int]) -> list[str] | None:
        """Which layer drove each row's last step, when the brake or the docking law is on:
        "brake" (it stopped the last step of dt), "docking law" (it has taken over), else
        "policy"; None for the paper's env and a policy alone."""
        if not output_keys(self._agent):
            return None
        aids = take_rows(self._aids, torch.tensor(indices, device=self.device))
        return ["brake" if braked else "docking law" if docked else "policy"
                for braked, docked in zip(aids.braked.tolist(), aids.docking_engaged.tolist(),
                                          strict=True)]

    # ------------------------------------------------------------------ EnvBase hooks
    def _outputs(self, **fields: torch.Tensor) -> TensorDictBase:
        # Copies: a later reset writes the env's tensors in place.
        state = self._fields(self._state, self._observation, self._cost)
        return TensorDict({**fields, **{k: v.clone() for k, v in state.items()}},
                          batch_size=self.batch_size, device=self.device)

    def _reset_output(self) -> TensorDictBase:
        no = torch.zeros(self.num_envs, 1, dtype=torch.bool, device=self.device)
        return self._outputs(**{key: no.clone() for key in END_FLAGS})

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n = self.num_envs
        if self.reset_in_step:  # from the ring: a select of every row, nothing read back
            if tensordict is not None and "_reset" in tensordict.keys() and self._started:
                mask = tensordict.get("_reset").reshape(n).to(self.device, torch.bool)
            else:  # the first reset draws every row, whatever the mask
                mask = torch.ones(n, dtype=torch.bool, device=self.device)
            self._ring_ready()
            rows, self._counters = self._reset_fn(
                mask, (self._state, self._observation, self._cost), self._ring, self._counters)
            self._state, self._observation, self._cost = rows
            self._unread += 1
            self._started = True
            return self._reset_output()
        if tensordict is not None and "_reset" in tensordict.keys() and self._started:
            # The rows to reset: the reset's one read-back (their count; on CUDA a sync).
            index = tensordict.get("_reset").reshape(n).nonzero()[:, 0]
        else:  # the first reset draws every row, whatever the mask
            index = torch.arange(n, device=self.device)
        return self._reset_rows(index)

    def _reset_rows(self, index: torch.Tensor) -> TensorDictBase:
        """The host path's reset of the rows ``index`` (B,) int64, sorted: the next B
        episodes drawn ahead, written in place; returns the reset's output for every row."""
        count = index.shape[0]
        if count > self.num_envs - self._ahead_used:
            self._draw_episodes_ahead()
        # The next `count` episodes drawn ahead, in the order of the rows' indices.
        taken = slice(self._ahead_used, self._ahead_used + count)
        self._write_rows(index, *take_rows(self._ahead, taken))
        self._ahead_used += count
        self._started = True
        return self._reset_output()

    def _step_and_maybe_reset(self, tensordict: TensorDictBase
                              ) -> tuple[TensorDictBase, TensorDictBase]:
        """torchrl's step and reset of the ended rows (what ``env.step_and_maybe_reset``, the
        rollouts and the collectors call), the reset put in as torchrl's generic merge would
        (:func:`_take_reset`): the same tensordicts as the generic path (tested), without its
        ``where`` per key."""
        if post_step_mdp_hooks(self) is not None:  # a hook of torchrl's: its generic path
            return super()._step_and_maybe_reset(tensordict)
        if tensordict.device != self.device:
            tensordict = tensordict.to(self.device)
        if self.reset_in_step:
            return self._step_and_reset(tensordict)
        tensordict = self.step(tensordict)
        tensordict_ = step_mdp(self, tensordict)
        # The ended rows: the path's one read-back (their count), where torchrl's reads
        # done.any() and the reset then the rows.
        index = tensordict.get(("next", "done")).reshape(self.num_envs).nonzero()[:, 0]
        count = index.shape[0]
        if count:
            # torchrl pads partial resets only
            pad = (lambda td: td.apply(lambda t: t.index_fill(0, index, 0))
                   ) if count < self.num_envs else None
            _take_reset(tensordict_, self._reset_rows(index), pad)
        return tensordict, tensordict_

    def _step_and_reset(self, tensordict: TensorDictBase
                        ) -> tuple[TensorDictBase, TensorDictBase]:
        """:meth:`_step_and_maybe_reset` with ``reset_in_step``: torchrl's step, whose
        :meth:`_step` runs the step and the reset of its ended rows as one function and keeps
        what the reset returns; then the reset's outputs taken as the host path takes them,
        the other keys zeroed in the ended rows on the device (nothing read back)."""
        tensordict, after = self.step_resetting(self.step, tensordict)
        done = tensordict.get(("next", "done")).reshape(self.num_envs)
        rows = done & ~done.all()  # torchrl pads partial resets only
        tensordict_ = step_mdp(self, tensordict)
        _take_reset(tensordict_, after, lambda td: td.masked_fill(rows, 0))
        return tensordict, tensordict_

    def step_resetting(self, step: Callable[[TensorDictBase], TensorDictBase],
                       tensordict: TensorDictBase) -> tuple[TensorDictBase, TensorDictBase]:
        """``step(tensordict)``, this env's ``step`` or that of a ``TransformedEnv`` around it,
        with the rows it ends reset inside this env's step function (``reset_in_step``).
        Returns its output (an ended row's last observation under "next") and what this
        env's reset returns for every row after it (the reset rows' new episodes, the other
        rows as they are, the end flags False)."""
        if not self.reset_in_step:
            raise RuntimeError("ParkingEnv.step_resetting needs reset_in_step=True")
        self._resetting = True
        try:
            tensordict = step(tensordict)
        finally:
            self._resetting = False
        after, self._after_reset = self._after_reset, None
        return tensordict, after

    def _draw_episodes_ahead(self) -> None:
        """Replace the host path's episodes not handed out yet by N new ones."""
        self._ahead, self._ahead_used = self._draw_episodes(), 0

    def _draw_episodes(self) -> tuple[AidedState, torch.Tensor, torch.Tensor]:
        """N new episodes (lots at the current occupancy, start poses, their first
        observations) drawn from the env's generator in one batch."""
        n = self.num_envs
        lots = draw_lots(n, self._occupancy, self.layout, self.config.lot, self._generator)
        near = self._agent.near_goal_starts
        near_draw = None if near is None else draw_near(self._world.goal_poses[lots.goal_slot],
                                                        near, self._generator)
        return self._new_episodes(lots, near_draw)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if not self._started:
            raise RuntimeError("ParkingEnv.step before reset: call env.reset() first")
        action = tensordict.get("action", None)
        if not isinstance(action, torch.Tensor):
            raise ValueError(f"the tensordict must hold an 'action' tensor of shape "
                             f"({self.num_envs}, 2) = (num_envs, [v, delta]), got "
                             f"{type(action).__name__}: set td['action'] before env.step(td)")
        if action.shape != (self.num_envs, 2):
            raise ValueError(
                f"action must have shape ({self.num_envs}, 2) = (num_envs, [v, delta]), "
                f"got {tuple(action.shape)}"
            )
        if action.device != self.device:
            raise ValueError(f"action must be on the env's device {self.device}, got "
                             f"{action.device}")
        if action.dtype not in (torch.float32, torch.float64):
            raise ValueError(f"action must be float32 (or float64, rounded to float32), got "
                             f"{action.dtype}")
        action = action.detach().to(torch.float32)
        if self._resetting:  # from _step_and_reset: the step and its reset, one function
            self._ring_ready()
            rows, reached, after, self._counters, self._bad_action = self._step_reset_fn(
                self._state, action, self._ring, self._counters, self._bad_action)
            self._unread += 1
            self._state, self._observation, self._cost = rows
            self._after_reset = TensorDict(after, batch_size=self.batch_size,
                                           device=self.device)
            return TensorDict(reached, batch_size=self.batch_size, device=self.device)
        if self.reset_in_step:  # the action check read with the ring's counters
            state, out, self._bad_action = self._guarded_fn(self._state, action,
                                                            self._bad_action)
        else:  # the same guarded step, its flag read now (free on a CPU)
            state, out, bad = self._guarded_fn(self._state, action, self._no_bad_action)
            if self.validate_actions and bool(bad):  # before the state is kept
                raise ValueError("action must be finite (no NaN or inf); got a non-finite "
                                 "value")
        self._state, self._observation, self._cost = state, out.observation, out.cost[:, 0]
        return self._outputs(**{k: v for k, v in out._asdict().items()
                                if k not in ("observation", "cost")})
