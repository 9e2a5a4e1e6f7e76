"""Past one process (trainers.distributed, trainers.collection): data-parallel PPO on gloo
ranks, and collection on torchrl's process, rpc and Ray backends. Every subprocess and every
test that starts workers has a timeout."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import psutil
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import VecNormV2
from torchrl.objectives.value import GAE

from tests import ddp_parity
from trainers.collection import RankCollection
from trainers.config import load_config
from trainers.distributed import World, merge_normalisers, norm_counts, rank_seed
from trainers.ppo import train
from trainers.utils import NORM_DECAY, NORMALISED, make_env, make_ppo_models

ROOT = Path(__file__).resolve().parents[1]
# One thread per rank on the 2-core CI machine; gloo over loopback; faulthandler in every
# process (the ranks inherit it), so a run that hangs prints where each of them waits.
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "GLOO_SOCKET_IFNAME": "lo",
       "PYTHONFAULTHANDLER": "1"}


def run(args: list[str], timeout: float) -> None:
    """Run ``python args``; past ``timeout`` s abort it and every process it started (torchrun
    starts its ranks in sessions of their own): each prints its threads' stacks, those still
    alive 20 s later are killed (none is left holding a port or the output's pipe), and the
    test fails with the output."""
    with subprocess.Popen([sys.executable, *args], cwd=ROOT, env=ENV, text=True,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            launcher = psutil.Process(proc.pid)
            tree = [launcher, *launcher.children(recursive=True)]
            for process in tree:
                with contextlib.suppress(psutil.NoSuchProcess):
                    process.send_signal(signal.SIGABRT)
            _, alive = psutil.wait_procs(tree, timeout=20)
            for process in alive:
                with contextlib.suppress(psutil.NoSuchProcess):
                    process.kill()
            out, err = proc.communicate()
            pytest.fail(f"{' '.join(args)} ran past {timeout} s (aborted with every process "
                        f"it started; their stacks last):\n{out[-3000:]}{err[-20000:]}")
    assert proc.returncode == 0, out[-3000:] + err[-3000:]


@pytest.mark.slow
@pytest.mark.timeout(300)  # above its launch of up to 120 s: its own kill fires first
def test_ddp_takes_the_update_of_one_process_on_the_global_batch(tmp_path):
    # A real batch: the smoke env stepped by the initial policy, with GAE's advantages.
    torch.manual_seed(0)
    loss = ddp_parity.make_loss()
    env = make_env(load_config("smoke"))
    with torch.no_grad():
        batch = env.rollout(64, loss.actor_network, break_when_any_done=False)
        GAE(gamma=0.99, lmbda=0.95, value_network=loss.critic_network)(batch)
    flat = batch.reshape(-1)
    assert flat.shape[0] == ddp_parity.BATCH
    # Train a policy whose std differs from the one that collected: with the collecting
    # policy itself, the log-std's first gradients are a near-cancelling sum (zero-mean
    # advantages times z^2 - 1) that Adam scales up to a full step, so its rounding (which
    # differs between CPUs' kernels) would decide the comparison: ill-posed, not compared.
    with torch.no_grad():
        for name, param in loss.named_parameters():
            if name.endswith("log_std"):
                param.sub_(0.5)
    torch.save(flat.to_dict(), tmp_path / "batch.pt")
    torch.save(loss.state_dict(), tmp_path / "init.pt")

    # One process on each whole minibatch.
    initial = torch.cat([p.detach().reshape(-1) for p in loss.parameters()])
    single = ddp_parity.steps(loss, ddp_parity.load(tmp_path, loss), 0, 1)
    run(["-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
         "-m", "tests.ddp_parity", str(tmp_path)], timeout=120)
    ddp = [torch.load(tmp_path / f"ddp_rank{r}.pt", weights_only=True) for r in range(2)]
    nosync = [torch.load(tmp_path / f"nosync_rank{r}.pt", weights_only=True)
              for r in range(2)]
    assert (single - initial).abs().max() > 1e-3  # the steps moved the networks
    assert torch.equal(ddp[0], ddp[1])
    assert (ddp[0] - single).abs().max() <= 1e-6
    # Without the all-reduce each rank follows its own half of the batch.
    assert not torch.equal(nosync[0], nosync[1])
    assert (nosync[0] - single).abs().max() > 1e-4


def test_merged_normalisers_hold_what_one_normaliser_of_the_global_batch_holds():
    # Two copies forgetting at NORM_DECAY ** 2, each fed half of every step's batch; their
    # merged statistics after the batch against one normaliser fed all of it.
    torch.manual_seed(0)
    steps = [torch.randn(16, 5) * 3 + 1 for _ in range(40)]

    def normaliser(decay: float) -> VecNormV2:
        return VecNormV2(in_keys=["x"], out_keys=["y"], decay=decay, reduce_batch_dims=True)

    def feed(norm: VecNormV2, rows: slice) -> None:
        for x in steps:
            norm._step(TensorDict(x=x[rows], batch_size=[x[rows].shape[0]]),
                       TensorDict(x=x[rows], batch_size=[x[rows].shape[0]]))

    one = normaliser(NORM_DECAY)
    feed(one, slice(None))
    copies = [normaliser(NORM_DECAY ** 2) for _ in range(2)]
    feed(copies[0], slice(0, 8))
    feed(copies[1], slice(8, 16))
    merged = merge_normalisers([c.state_dict() for c in copies], None)
    expected = one.state_dict()["_extra_state"]
    for key, value in merged["_extra_state"].items():
        if key.startswith("count"):
            assert int(value) == int(expected[key]) == 16 * 40
        else:
            torch.testing.assert_close(value, expected[key], rtol=1e-5, atol=1e-6)
    assert {k: int(v) for k, v in norm_counts(merged).items()} == {"count.-|-.x": 640}


def test_rank_seeds_are_distinct_and_one_rank_keeps_the_seed():
    assert rank_seed(7, 0, 1) == 7
    seeds = {rank_seed(s, r, 4) for s in range(50) for r in range(4)}
    assert len(seeds) == 200


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_two_ranks_train_end_to_end_and_resume_on_one(tmp_path):
    run(["-m", "trainers.ppo", "--preset", "smoke", "dist.world_size=2",
         f"logger.log_dir={tmp_path / 'two'}"], timeout=240)
    run_dir = tmp_path / "two" / "smoke"
    final = torch.load(run_dir / "checkpoint_final.pt", weights_only=True)
    assert final["frames"] == 4096  # the config's global frames, half from each rank
    # The curriculum counted the global frames: phase 5 of 1024 frames per level.
    assert int(final["env"]["transforms.3.frames"]) == 4096
    # Each rank's own lots and seed; the checkpoint holds both for an exact resume.
    ranks = final["ranks"]
    assert len(ranks) == 2
    assert not torch.equal(ranks[0]["sim"]["state.pose"], ranks[1]["sim"]["state.pose"])
    # The merged normaliser counted every observation of both ranks: more than the steps
    # of the whole run (4096, plus the reset observations).
    counts = [int(v) for k, v in final["obs_norm"]["_extra_state"].items()
              if k.startswith("count")]
    assert counts and counts[0] > 4096

    # A two-rank checkpoint resumes on one rank: the schedule goes on from 2048 frames.
    cfg = load_config("smoke", [f"logger.log_dir={tmp_path / 'one'}"])
    resumed = torch.load(train(cfg, resume=str(run_dir / "checkpoint_2048.pt")),
                         weights_only=True)
    assert resumed["frames"] == 4096
    assert int(resumed["env"]["transforms.3.frames"]) == 4096
    assert "ranks" not in resumed and "sim" in resumed


def test_dist_config_errors_name_the_field():
    for overrides, field in (
        (["dist.world_size=0"], "dist.world_size"),
        (["dist.collectors=threads"], "dist.collectors"),
        (["dist.collectors=distributed", "dist.num_collectors=2"], "dist.collectors"),
        (["dist.num_collectors=2"], "dist.num_collectors"),
        (["dist.world_size=3"], "env.num_envs"),
        (["dist.world_size=2", "loss.mini_batch_size=255"], "loss.mini_batch_size"),
        (["dist.world_size=2", "optim.compile_update=true"], "optim.compile_update"),
    ):
        with pytest.raises(ValueError, match=field.replace(".", r"\.")):
            load_config("smoke", overrides)


def test_more_ranks_than_cores_are_refused_before_anything_is_written(tmp_path, monkeypatch,
                                                                     capsys):
    """dist.world_size=4 on a 2-core machine: one line, no run folder, no rank started."""
    import os

    from trainers.ppo import main

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    with pytest.raises(SystemExit) as refused:
        main(["--preset", "smoke", "dist.world_size=4", f"logger.log_dir={tmp_path / 'run'}"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert refused.value.code == 2
    assert "dist.world_size=4 ranks on this machine's 2 CPU core(s)" in err, err
    assert not (tmp_path / "run").exists()


def backends() -> list:
    try:
        import ray  # noqa: F401
        ray_param = pytest.param("ray")
    except ImportError:
        ray_param = pytest.param("ray", marks=pytest.mark.skip(
            reason="Ray is not installed (pip install -e '.[ray]')"))
    return ["process", "rpc", ray_param]


@pytest.mark.slow
@pytest.mark.timeout(240)
@pytest.mark.parametrize("backend", backends())
def test_collector_workers(backend):
    cfg = load_config("smoke", [f"dist.collectors={backend}", "dist.num_collectors=2"])
    probe = make_env(cfg, num_envs=1)
    actor, _ = make_ppo_models(probe.observation_spec[NORMALISED].shape[-1],
                               probe.action_spec, cfg.model)
    collection = RankCollection(cfg, actor, World(), cfg.collector.total_frames)
    try:
        collection.spread_timeouts()
        batches = iter(collection.collector)
        batch = next(batches)
        # 16 envs over 2 workers, 1024 env steps a batch: 8 envs x 64 steps each; rpc
        # stacks the workers' envs.
        assert batch.shape == ((16, 64) if backend == "rpc" else (2, 8, 64))
        obs = batch["observation"].reshape(2, 8, 64, -1)
        # Decorrelated: each worker its own lots (and its own seed).
        assert not torch.equal(obs[0, :, 0], obs[1, :, 0])
        # Spread timeouts: the first episodes do not all end at the same step.
        steps = collection.call("env.base_env.state")
        assert all(len(set(s.steps.tolist())) > 1 for s in steps)

        # Fresh weights reach the workers.
        with torch.no_grad():
            for p in actor.parameters():
                p.add_(0.25)
        collection.collector.update_policy_weights_()
        mine = torch.cat([p.reshape(-1) for p in actor.parameters()])
        for theirs in collection.call("policy.state_dict"):
            flat = torch.cat([v.reshape(-1).cpu() for v in theirs.values()
                              if v.is_floating_point()])
            assert torch.isin(mine, flat).all()

        # The workers' normalisers merged: the same statistics everywhere, every
        # observation counted once; the learner's env holds them and the global frames.
        before = collection.call("env.transform[-1].state_dict")
        collection.sync_normalisers()
        after = collection.call("env.transform[-1].state_dict")
        key = next(k for k in after[0]["_extra_state"] if k.startswith("count"))
        assert int(after[0]["_extra_state"][key]) == sum(
            int(b["_extra_state"][key]) for b in before)
        for name, value in after[0]["_extra_state"].items():
            assert torch.equal(value, after[1]["_extra_state"][name])
            assert torch.equal(value, collection.env.transform[-1].state_dict()
                               ["_extra_state"][name])
        # Both workers' curricula counted the global frames.
        frames = collection.call("env.transform[3].frames_seen")
        assert frames == [1024, 1024]
        assert collection.env.transform[3].frames_seen == 1024

        # A checkpoint's state loaded into every worker (a resume): the next merge counts
        # its observations once, and adds what each worker saw since.
        collection.load_env_state(collection.env.state_dict())
        loaded = int(collection.env.transform[-1].state_dict()["_extra_state"][key])
        next(batches)
        seen = [int(s["_extra_state"][key]) - loaded
                for s in collection.call("env.transform[-1].state_dict")]
        collection.sync_normalisers()
        merged = collection.call("env.transform[-1].state_dict")[0]["_extra_state"][key]
        assert int(merged) == loaded + sum(seen) and min(seen) > 0
        assert collection.call("env.transform[3].frames_seen") == [2048, 2048]
    finally:
        collection.shutdown()
        if backend == "ray":
            import ray
            ray.shutdown()
