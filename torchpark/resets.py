"""Where a ``ParkingEnv``'s new episodes come from, and how they reach the rows that reset.

:class:`EpisodeDraw` draws N new episodes at a time from the env's generator (lots at the
current occupancy, start poses, their first observations: one batched call, compiled with the
step). A :class:`Resets` engine hands them out in order, each once, to the rows that reset,
and runs the env's steps:

- :class:`HostResets`, the host path: one block of N drawn ahead; a reset of B rows writes
  them in place (a gather and a scatter of B rows) and reads their count back (on CUDA a
  synchronisation, beside torchrl's ``done.any()``).
- :class:`RingResets` (``reset_in_step``, :mod:`torchpark.sim.ring`): a ring of blocks drawn
  ahead, handed out by device counters that the host reads once every ``blocks_ahead``
  hand-outs; the rows a step ends reset inside the step's own graph, with no data-dependent
  shape. Each such step writes every row (a select over the whole state), which costs more
  than the host path's scatter on a CPU, where a read-back costs nothing.

Both give the same rows the same episodes in the same order, so the same seed gives the same
rollout on either (``tests/test_ring.py``), under every setter of the env: what changes the
episodes to come discards those drawn ahead (:meth:`Resets.discard`), and what draws from the
generator first puts it where the host path has it (:meth:`Resets.redraw_ahead`). A step
inside ``with resets.resetting() as reset:`` also resets the rows it ends, and ``reset``
then holds what that reset returned.

A non-finite action sets no row's pose: its row takes (0, 0) and stands still on either path.
With ``validate_actions`` the host path raises at once (its flag read after the step, the
state left as it was) and the ring at its next read of the counters.
"""

from __future__ import annotations

import contextlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor

from torchpark.aids.starts import NearGoalStarts, draw_near
from torchpark.config import LotConfig, is_integer
from torchpark.rows import Rows, check_rows, flat_rows, unflat_rows
from torchpark.sim.episodes import draw_lots
from torchpark.sim.layout import LotLayout
from torchpark.sim.ring import END_FLAGS, Counters, guarded_step, reset_rows, step_and_reset
from torchpark.sim.step import put_rows_, take_rows
from torchpark.sim.world import World

# With reset_in_step, at most this many blocks of N episodes drawn ahead: a host read every
# 256 steps costs nothing measurable, and the first reset draws every block.
MAX_BLOCKS_AHEAD = 256

BAD_ACTION = "action must be finite (no NaN or inf)"


class EpisodeDraw:
    """N new episodes at a time from ``generator``: lots at ``occupancy`` (settable),
    start poses (near the goal with ``near`` starts: ``near_goal_starts``), their first
    observations and costs.
    ``new_episodes(lots, near_draw) -> (state, observation, cost)`` is the env's reset of B
    rows (:func:`torchpark.aids.step.aided_new_episodes`, bound, compiled or not)."""

    def __init__(self, num_envs: int, occupancy: float, layout: LotLayout, lot: LotConfig,
                 world: World, near: NearGoalStarts | None, new_episodes: Callable,
                 generator: torch.Generator) -> None:
        self.num_envs, self.occupancy, self.generator = num_envs, occupancy, generator
        self.near_goal_starts = near
        self._layout, self._lot, self._world = layout, lot, world
        self._new_episodes = new_episodes

    def __call__(self) -> Rows:
        lots = draw_lots(self.num_envs, self.occupancy, self._layout, self._lot, self.generator)
        near = None if self.near_goal_starts is None else draw_near(
            self._world.goal_poses[lots.goal_slot], self.near_goal_starts, self.generator)
        return Rows(*self._new_episodes(lots, near))


@dataclass
class Reset:
    """What the reset inside a step did (:meth:`Resets.resetting`): ``output``, the env's
    reset output for every row (the reset rows' new episodes, the other rows as the step
    left them, the end flags False), None where the engine knows no row was reset; ``pad``,
    which makes the other keys of the next step's root zeroed in the reset rows (torchrl pads
    a partial reset only), None where none is to be zeroed."""

    output: TensorDictBase | None = None
    pad: Callable[[TensorDictBase], TensorDictBase] | None = None


class Resets(ABC):
    """The interface of the two engines: steps (:meth:`Resets.step`), resets of a mask's rows
    (:meth:`Resets.reset`), the episodes drawn ahead discarded (:meth:`Resets.discard`), their
    state as a snapshot's entries. ``step(state, action) -> (state, StepResult, finite)`` is
    the env's step; ``fields(state, observation, cost) -> dict`` its outputs read from rows
    (views); ``build(functions) -> functions`` compiles them or not."""

    #: What the env's snapshot says of its reset path (``build``'s entries).
    reset_in_step = False
    ring_blocks = 0

    def __init__(self, draw: EpisodeDraw, step: Callable, fields: Callable, build: Callable,
                 validate_actions: bool) -> None:
        self.draw, self.validate_actions = draw, validate_actions
        self._n, self._device = draw.num_envs, draw.generator.device
        self._fields = fields
        self._guarded, *self._more = build([partial(guarded_step, step), *self._functions(step)])
        self._reset: Reset | None = None

    @staticmethod
    @abstractmethod
    def ahead(blocks_ahead: int) -> tuple[int, str]:
        """The blocks of N episodes the engine holds drawn ahead, given the env's
        ``blocks_ahead``, and the argument that sets them as an error names it ("" where
        none does)."""

    def _functions(self, step: Callable) -> list[Callable]:
        """The engine's own functions to build beside the guarded step."""
        return []

    def _tensordict(self, fields: dict[str, Tensor]) -> TensorDict:
        return TensorDict(fields, batch_size=[self._n], device=self._device)

    def outputs(self, rows: Rows, **fields: Tensor) -> TensorDict:
        """``fields`` and copies of the outputs read from ``rows`` (a later reset writes the
        rows in place)."""
        read = {k: v.clone() for k, v in self._fields(*rows).items()}
        return self._tensordict({**fields, **read})

    def reset_output(self, rows: Rows) -> TensorDict:
        """What a reset returns for ``rows``: their outputs, the end flags False."""
        no = torch.zeros(self._n, 1, dtype=torch.bool, device=self._device)
        return self.outputs(rows, **{key: no.clone() for key in END_FLAGS})

    @contextlib.contextmanager
    def resetting(self) -> Iterator[Reset]:
        """Inside it, each step also resets the rows it ends; the :class:`Reset` yielded says
        what that reset returned."""
        self._reset = reset = Reset()
        try:
            yield reset
        finally:
            self._reset = None

    def step(self, rows: Rows, action: Tensor) -> tuple[Rows, TensorDict]:
        """One step of ``rows`` at ``action`` (N, 2) float32 (inside :meth:`resetting`, and
        the reset of the rows it ends): the rows after it and the step's outputs."""
        if self._reset is not None:
            return self._step_and_reset(rows, action, self._reset)
        return self._step(rows, action)

    @abstractmethod
    def _step(self, rows: Rows, action: Tensor) -> tuple[Rows, TensorDict]:
        """The step alone."""

    @abstractmethod
    def _step_and_reset(self, rows: Rows, action: Tensor, reset: Reset
                        ) -> tuple[Rows, TensorDict]:
        """The step and the reset of the rows it ends, what that reset returned put in
        ``reset``."""

    def _stepped(self, rows: Rows, action: Tensor, bad: Tensor
                 ) -> tuple[Rows, TensorDict, Tensor]:
        """The guarded step (a non-finite action's row stands still): the rows after it, its
        outputs and whether an action was not finite, () bool."""
        state, out, bad = self._guarded(rows.state, action, bad)
        rows = Rows(state, out.observation, out.cost[:, 0])
        return rows, self.outputs(rows, **{k: v for k, v in out._asdict().items()
                                           if k not in ("observation", "cost")}), bad

    @abstractmethod
    def reset(self, rows: Rows, mask: Tensor | None) -> Rows:
        """The rows where ``mask`` (N,) bool (None: every row) given the next episodes."""

    @abstractmethod
    def discard(self) -> None:
        """Hand out none of the episodes drawn so far: later resets draw new ones (from the
        generator, at the occupancy and against the success threshold of that time)."""

    def spread_steps(self, rows: Rows, max_steps: int) -> Rows:
        """``rows`` with every step count a uniform draw in [0, ``max_steps``) from the
        generator, drawn where the host path would draw it (:meth:`redraw_ahead`)."""
        self.redraw_ahead()
        steps = torch.randint(max_steps, rows.cost.shape, generator=self.draw.generator,
                              device=rows.cost.device)
        return rows._replace(state=rows.state._replace(sim=rows.state.sim._replace(steps=steps)))

    def threshold_changed(self) -> None:
        """The success threshold changes: episodes drawn ahead with near-goal starts, which
        are drawn clear of the success test, are discarded (the others do not depend on
        it)."""
        if self.draw.near_goal_starts is not None:
            self.discard()

    @abstractmethod
    def redraw_ahead(self) -> None:
        """Before something else draws from the generator: put it where the host path, which
        draws a block only when it needs one, has it, and draw later blocks after that draw."""

    @abstractmethod
    def snapshot(self) -> dict[str, Tensor | int]:
        """The engine's state as a snapshot's entries (copies)."""

    @abstractmethod
    def check(self, snapshot: dict, slots: int) -> None:
        """ValueError naming the first of the engine's entries of ``snapshot`` that does not
        fit (entries of the right names, shapes and dtypes; ``slots`` goal slots)."""

    @abstractmethod
    def load(self, snapshot: dict) -> None:
        """Continue from the engine's entries of a :meth:`check`-ed snapshot."""


class HostResets(Resets):
    """The host path: one block of N episodes drawn ahead, the first ``used`` of them handed
    out; a reset reads its rows' count and writes them in place."""

    def __init__(self, draw: EpisodeDraw, step: Callable, fields: Callable, build: Callable,
                 validate_actions: bool, ahead: Rows) -> None:
        super().__init__(draw, step, fields, build, validate_actions)
        self._ahead, self._used = ahead, draw.num_envs
        self._no_bad = torch.tensor(False, device=self._device)

    @staticmethod
    def ahead(blocks_ahead: int) -> tuple[int, str]:
        return 1, ""

    def _step(self, rows: Rows, action: Tensor) -> tuple[Rows, TensorDict]:
        rows, outputs, bad = self._stepped(rows, action, self._no_bad)
        if self.validate_actions and bool(bad):  # before the env keeps the rows
            raise ValueError(f"{BAD_ACTION}; got a non-finite value")
        return rows, outputs

    def _step_and_reset(self, rows: Rows, action: Tensor, reset: Reset
                        ) -> tuple[Rows, TensorDict]:
        rows, outputs = self._step(rows, action)
        # The ended rows: the path's one read-back (their count).
        index = outputs["done"].reshape(self._n).nonzero()[:, 0]
        count = index.shape[0]
        if count:
            rows = self._hand_out(rows, index)
            reset.output = self.reset_output(rows)
            if count < self._n:
                reset.pad = lambda td: td.apply(lambda t: t.index_fill(0, index, 0))
        return rows, outputs

    def reset(self, rows: Rows, mask: Tensor | None) -> Rows:
        index = (torch.arange(self._n, device=self._device) if mask is None
                 else mask.nonzero()[:, 0])  # the reset's one read-back (their count)
        return self._hand_out(rows, index)

    def _hand_out(self, rows: Rows, index: Tensor) -> Rows:
        """The rows ``index`` (B,) int64, sorted, given the next B episodes drawn ahead, in
        place."""
        count = index.shape[0]
        if count > self._n - self._used:
            self._ahead, self._used = self.draw(), 0
        put_rows_(rows, index, take_rows(self._ahead, slice(self._used, self._used + count)))
        self._used += count
        return rows

    def discard(self) -> None:
        self._used = self._n

    def redraw_ahead(self) -> None:
        """Nothing: the host path draws a block only when it needs one."""

    def snapshot(self) -> dict[str, Tensor | int]:
        return {**flat_rows(self._ahead, "ahead."), "ahead_used": self._used}

    def check(self, snapshot: dict, slots: int) -> None:
        used = snapshot["ahead_used"]
        if not is_integer(used) or not 0 <= used <= self._n:
            raise ValueError(f"snapshot['ahead_used'] must be an int in [0, {self._n}], got "
                             f"{used!r}")
        check_rows(unflat_rows(snapshot, self._device, "ahead."), slots,
                   "snapshot['ahead.state']", "snapshot['ahead.observation'] and ['ahead.cost']")

    def load(self, snapshot: dict) -> None:
        self._ahead = unflat_rows(snapshot, self._device, "ahead.")
        self._used = int(snapshot["ahead_used"])


class RingResets(Resets):
    """``reset_in_step``: a ring of ``blocks_ahead + 1`` blocks of N episodes and its device
    counters (:mod:`torchpark.sim.ring`). Block 0 stands for no block (all used); the host
    has drawn blocks [0, drawn), last read block ``known`` and let ``unread`` hand-outs run
    since. A non-finite action's flag is read with the counters."""

    reset_in_step = True

    def __init__(self, draw: EpisodeDraw, step: Callable, fields: Callable, build: Callable,
                 validate_actions: bool, ring: Rows) -> None:
        super().__init__(draw, step, fields, build, validate_actions)
        self._step_reset, self._reset_rows = self._more
        self._ring = ring
        self.ring_blocks = ring.cost.shape[0] // self._n
        self._counters = Counters(torch.tensor(0, device=self._device),
                                  torch.tensor(self._n, device=self._device))
        self._bad = torch.tensor(False, device=self._device)
        self._drawn, self._known, self._unread = 1, 0, 0
        # the generator's state before each block was drawn (by slot), for discard
        self._rng = [draw.generator.get_state()] * self.ring_blocks

    @staticmethod
    def ahead(blocks_ahead: int) -> tuple[int, str]:
        return blocks_ahead + 1, f", blocks_ahead={blocks_ahead}"

    def _functions(self, step: Callable) -> list[Callable]:
        # the step and the reset of the rows it ends as one function; a mask's rows' reset
        return [partial(step_and_reset, step, self._fields), reset_rows]

    def _step(self, rows: Rows, action: Tensor) -> tuple[Rows, TensorDict]:
        rows, outputs, self._bad = self._stepped(rows, action, self._bad)
        return rows, outputs

    def _step_and_reset(self, rows: Rows, action: Tensor, reset: Reset
                        ) -> tuple[Rows, TensorDict]:
        self._ready()
        rows, reached, after, self._counters, self._bad = self._step_reset(
            rows.state, action, self._ring, self._counters, self._bad)
        self._unread += 1
        done = reached["done"].reshape(self._n)
        partial_reset = done & ~done.all()  # torchrl pads partial resets only
        reset.output = self._tensordict(after)
        reset.pad = lambda td: td.masked_fill(partial_reset, 0)
        return Rows(*rows), self._tensordict(reached)

    def reset(self, rows: Rows, mask: Tensor | None) -> Rows:
        # a select of every row, nothing read back
        mask = torch.ones(self._n, dtype=torch.bool, device=self._device) if mask is None \
            else mask
        self._ready()
        rows, self._counters = self._reset_rows(mask, rows, self._ring, self._counters)
        self._unread += 1
        return Rows(*rows)

    def _ready(self) -> None:
        """Before a hand-out: make sure the block it may move to is drawn. Where the host can
        no longer tell, it reads the counters (and the non-finite action flag) back, once,
        and draws the blocks spent since, in order."""
        if self._known + self._unread + 2 <= self._drawn:
            return
        block, bad = torch.stack((self._counters.block, self._bad.long())).tolist()
        if bad and self.validate_actions:
            self._bad.fill_(False)
            raise ValueError(f"{BAD_ACTION}; a non-finite value reached a step since the env's "
                             f"last read of its counters (its rows stood still)")
        self._known, self._unread = block, 0
        n = self._n
        while self._drawn < block + self.ring_blocks:
            slot = self._drawn % self.ring_blocks
            self._rng[slot] = self.draw.generator.get_state()
            put_rows_(self._ring, torch.arange(slot * n, (slot + 1) * n, device=self._device),
                      self.draw())
            self._drawn += 1

    def discard(self) -> None:
        self.redraw_ahead()
        self._counters.used.fill_(self._n)  # the current block's rest as well

    def redraw_ahead(self) -> None:
        """One read of the counters, the blocks drawn ahead of the current one dropped and
        the generator put back to where it was before them: the host path has drawn no
        further, so both draw the same lots next."""
        block = int(self._counters.block)
        if self._drawn > block + 1:
            self.draw.generator.set_state(self._rng[(block + 1) % self.ring_blocks])
        self._drawn, self._known, self._unread = block + 1, block, 0

    def snapshot(self) -> dict[str, Tensor | int]:
        return {**flat_rows(self._ring, "ring."), "ring_drawn": self._drawn,
                "ring_counters": torch.stack((*self._counters, self._bad.long())),
                "ring_generators": torch.stack(self._rng)}

    def check(self, snapshot: dict, slots: int) -> None:
        block, used, bad = snapshot["ring_counters"].tolist()
        drawn = snapshot["ring_drawn"]
        if not (is_integer(drawn) and 0 <= block < drawn <= block + self.ring_blocks
                and 0 <= used <= self._n and bad in (0, 1)):
            raise ValueError(f"snapshot['ring_counters'] (block, used, bad action) and "
                             f"['ring_drawn'] must satisfy 0 <= block < drawn <= block + "
                             f"{self.ring_blocks}, used in [0, {self._n}], bad 0 or 1; got "
                             f"{(block, used, bad)}, {drawn!r}")
        for i, state in enumerate(snapshot["ring_generators"]):
            check_generator_state(state.clone(), self._device,  # set_state reads whole tensors
                                  f"snapshot['ring_generators'][{i}]")
        check_rows(unflat_rows(snapshot, self._device, "ring."), slots,
                   "snapshot['ring.state']", "snapshot['ring.observation'] and ['ring.cost']")

    def load(self, snapshot: dict) -> None:
        self._ring = unflat_rows(snapshot, self._device, "ring.")
        self._rng = [state.clone() for state in snapshot["ring_generators"]]
        counters = snapshot["ring_counters"].to(self._device, copy=True)
        self._counters, self._bad = Counters(counters[0], counters[1]), counters[2] > 0
        self._drawn, self._known, self._unread = int(snapshot["ring_drawn"]), int(counters[0]), 0


def check_generator_state(state: Tensor, device: torch.device, name: str) -> None:
    """ValueError naming ``name`` unless ``state`` is a state of ``device``'s random
    generator (one of the right size may still be none)."""
    try:
        torch.Generator(device=device).set_state(state)
    except RuntimeError as err:
        raise ValueError(f"{name} is not a state of this device's random generator: "
                         f"{str(err).splitlines()[0]}") from None
