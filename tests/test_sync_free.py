"""The training env's path with no host read per step (``torchpark.transforms.sync_free``):
torchrl's generic tensordicts bit for bit, the normaliser's statistics included; one read per
collector batch (the ring's); a policy that compiles whole, so that it reads nothing back."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.envs import RewardScaling, TransformedEnv, VecNormV2

import trainers.utils
from tests.conftest import random_actions
from tests.test_ring import reads_counted
from torchpark.compiling import compiler_found
from trainers.collection import RankCollection
from trainers.config import load_config
from trainers.distributed import World
from trainers.utils import NORMALISED, build_models, make_env


def generic(monkeypatch, cfg):
    """``make_env(cfg)`` with torchrl's own classes in place of the sync-free ones."""
    with monkeypatch.context() as patched:
        patched.setattr(trainers.utils, "SyncFreeEnv", TransformedEnv)
        patched.setattr(trainers.utils, "SyncFreeVecNorm", VecNormV2)
        patched.setattr(trainers.utils, "SyncFreeRewardScaling", RewardScaling)
        return make_env(cfg)


# Short episodes in a full lot: every row ends at max_steps (steps of dt) unless it collided
# before; fast's brake stops its collisions, so its rows all end together.
@pytest.mark.parametrize("preset, max_steps, steps", [("smoke", 4, 40), ("fast", 20, 12)])
def test_the_sync_free_path_gives_torchrls_generic_path(monkeypatch, preset, max_steps, steps):
    cfg = load_config(preset, ["env.num_envs=8", "collector.frames_per_batch=640",
                               "loss.mini_batch_size=64", "env.reset_in_step=true",
                               f"env.task.max_steps={max_steps}", "curriculum.levels=[0.9]",
                               "env.compile_step=false"])  # the same math eager
    ours, theirs = make_env(cfg), generic(monkeypatch, cfg)
    assert type(theirs) is TransformedEnv and type(ours) is not TransformedEnv
    td, td_theirs = ours.reset(), theirs.reset()
    ended = []
    for action in random_actions(8, steps, 1):
        out, td = ours.step_and_maybe_reset(td.set("action", action.clone()))
        out_theirs, td_theirs = theirs.step_and_maybe_reset(td_theirs.set("action", action))
        for a, b in ((out, out_theirs), (td, td_theirs)):
            assert set(a.keys(True, True)) == set(b.keys(True, True))
            for key in a.keys(True, True):
                assert torch.equal(a[key], b[key]), key
        ended.append(int(out["next", "done"].sum()))
    assert 0 in ended and 8 in ended  # steps that end no row, every row
    assert preset == "fast" or any(0 < n < 8 for n in ended)  # and some rows
    norm, norm_theirs = ours.transform[-1], theirs.transform[-1]
    for mine, other in ((norm._loc, norm_theirs._loc), (norm._var, norm_theirs._var),
                        (norm._count, norm_theirs._count)):
        assert (mine == other).all()


@pytest.mark.slow
def test_the_training_collector_reads_back_once_per_batch(monkeypatch):
    """RankCollection's collector over the env resetting in its step, with a policy that reads
    nothing (the trainer's TanhNormal reads its bounds when eager; compiled, it does not:
    next test): one read per batch of 8 steps, the ring's; the generic path reads at every
    step."""
    steps = 8
    cfg = load_config("smoke", ["env.num_envs=16", f"collector.frames_per_batch={16 * steps}",
                                "loss.mini_batch_size=64", "env.reset_in_step=true",
                                "env.task.max_steps=6", "curriculum.levels=[0.9]"])
    policy = TensorDictModule(lambda obs: torch.tanh(obs[:, :2]) * torch.tensor([5.0, 0.785]),
                              in_keys=[NORMALISED], out_keys=["action"])

    def reads_per_batch() -> list[int]:
        collector = RankCollection(cfg, policy, World(device=torch.device("cpu")),
                                   10 ** 6).collector
        batches = iter(collector)
        next(batches)  # the first reset and draws
        counts = []
        for _ in range(3):
            with reads_counted(monkeypatch) as count:
                next(batches)
                counts.append(count())
        collector.shutdown()
        return counts

    assert max(reads_per_batch()) <= 1
    monkeypatch.setattr(trainers.utils, "SyncFreeEnv", TransformedEnv)
    assert min(reads_per_batch()) >= steps


@pytest.mark.slow
@pytest.mark.skipif(not compiler_found(), reason="torch.compile needs a C++ compiler")
def test_the_policy_compiles_whole():
    """The trainer's actor in one graph (fullgraph) with no scalar or data-dependent output
    allowed, so no read back; the same action as eager in the deterministic mode."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    actor, _ = build_models(load_config("fast"))
    width = actor.module[0].module[0][0].in_features
    td = TensorDict({NORMALISED: torch.randn(32, width, generator=torch.Generator()
                                              .manual_seed(0))}, batch_size=[32])
    config = torch._dynamo.config
    with config.patch(capture_dynamic_output_shape_ops=False, capture_scalar_outputs=False):
        torch._dynamo.reset()
        compiled = torch.compile(actor, fullgraph=True)
        sampled = compiled(td.clone())
        assert sampled["action"].shape == (32, 2)
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            ours = compiled(td.clone())["action"]
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        eager = actor(td.clone())["action"]
    torch.testing.assert_close(ours, eager)
