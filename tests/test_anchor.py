"""PPO's loss with the imitation term toward the actor a run started from (trainers.anchor),
and the runs that use it (trainers.ppo --init with loss.anchor_coef)."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded

from trainers.anchor import AnchoredPPOLoss
from trainers.config import ModelConfig, load_config
from trainers.ppo import main, train
from trainers.utils import NORMALISED, make_ppo_models

OBS = 5


def batch(distance: torch.Tensor) -> TensorDict:
    """A minibatch with the keys ClipPPOLoss reads; the goal ``distance`` (N,) m away."""
    n = distance.shape[0]
    observation = torch.zeros(n, 23)
    observation[:, 0] = distance
    return TensorDict({NORMALISED: torch.randn(n, OBS), "observation": observation,
                       "action": torch.rand(n, 2) * 1.8 - 0.9,
                       "action_log_prob": torch.zeros(n), "advantage": torch.randn(n, 1),
                       "value_target": torch.randn(n, 1)}, [n])


def models():
    torch.manual_seed(0)
    return make_ppo_models(OBS, Bounded(-1.0, 1.0, shape=(2,)),
                           ModelConfig(hidden=[16], state_dependent_std=True))


def test_the_anchor_term_is_the_squared_action_distance_near_the_goal_only():
    actor, critic = models()
    anchor = copy.deepcopy(actor)
    loss = AnchoredPPOLoss(actor, critic, anchor, coef=2.0, reach=8.0)
    near = batch(torch.full((64,), 3.0))
    assert loss(near)["loss_anchor"].item() == 0.0  # the actor is its anchor
    with torch.no_grad():
        for p in actor.parameters():
            p.add_(0.3 * torch.randn_like(p))
    td = near.clone()
    expected = (torch.tanh(actor.module[0](td.clone())["loc"])
                - torch.tanh(anchor.module[0](td.clone())["loc"])).pow(2).sum(-1).mean()
    torch.testing.assert_close(loss(near)["loss_anchor"], 2.0 * expected)
    # Half the states beyond the reach: only the near half counts (mean over all).
    mixed = batch(torch.cat([torch.full((32,), 3.0), torch.full((32,), 9.0)]))
    mixed[NORMALISED] = near[NORMALISED]
    per_state = (torch.tanh(actor.module[0](mixed.clone())["loc"])
                 - torch.tanh(anchor.module[0](mixed.clone())["loc"])).pow(2).sum(-1)
    torch.testing.assert_close(loss(mixed)["loss_anchor"], 2.0 * per_state[:32].sum() / 64)
    assert loss(batch(torch.full((64,), 9.0)))["loss_anchor"].item() == 0.0


def test_the_anchor_is_never_trained():
    actor, critic = models()
    anchor = copy.deepcopy(actor)
    with torch.no_grad():
        for p in actor.parameters():
            p.add_(0.3 * torch.randn_like(p))
    loss = AnchoredPPOLoss(actor, critic, anchor, coef=1.0, reach=8.0)
    frozen = {k: v.clone() for k, v in anchor.state_dict().items()}
    assert not {id(p) for p in anchor.parameters()} & {id(p) for p in loss.parameters()}
    optim = torch.optim.Adam(loss.parameters(), lr=1e-2)
    before = actor.module[0](batch(torch.full((8,), 1.0)))["loc"].detach()
    for _ in range(5):
        optim.zero_grad()
        loss(batch(torch.full((64,), 1.0)))["loss_anchor"].backward()
        optim.step()
    for key, value in anchor.state_dict().items():
        torch.testing.assert_close(value, frozen[key], rtol=0, atol=0)
    assert not torch.equal(actor.module[0](batch(torch.full((8,), 1.0)))["loc"], before)


@pytest.fixture(scope="module")
def start(tmp_path_factory):
    log_dir = tmp_path_factory.mktemp("runs")
    return train(load_config("smoke", [f"logger.log_dir={log_dir}"]))


def test_an_anchored_run_resumes_exactly(start, tmp_path):
    """Started from a checkpoint with the anchor on: the checkpoint half way holds the anchor
    (the start's actor), and the second half resumed from it repeats the whole run."""
    args = ["--preset", "smoke", "loss.anchor_coef=1.0", "loss.anchor_reach=100"]
    main([*args, "--init", str(start), f"logger.log_dir={tmp_path / 'whole'}"])
    half = tmp_path / "whole" / "smoke" / "checkpoint_2048.pt"
    saved = torch.load(half, weights_only=True)
    for key, value in torch.load(start, weights_only=True)["actor"].items():
        torch.testing.assert_close(saved["anchor"][key], value, rtol=0, atol=0)
    main([*args, "--resume", str(half), f"logger.log_dir={tmp_path / 'resumed'}"])
    whole = torch.load(tmp_path / "whole" / "smoke" / "checkpoint_final.pt", weights_only=True)
    resumed = torch.load(tmp_path / "resumed" / "smoke" / "checkpoint_final.pt",
                         weights_only=True)
    for key in ("actor", "critic", "optim", "anchor", "obs_norm", "sim"):
        torch.testing.assert_close(resumed[key], whole[key], rtol=0, atol=0, msg=key)


def test_an_anchor_without_a_start_is_refused(start, tmp_path):
    cfg = load_config("smoke", ["loss.anchor_coef=1.0", f"logger.log_dir={tmp_path}"])
    with pytest.raises(ValueError, match=r"loss\.anchor_coef=1\.0 .* pass --init"):
        train(cfg)
    with pytest.raises(ValueError, match=r"trained without loss\.anchor_coef"):
        train(cfg, resume=str(start))
    for bad in ("loss.anchor_coef=nan", "loss.anchor_reach=0"):
        with pytest.raises(ValueError, match=bad.split("=")[0].replace(".", r"\.")):
            load_config("smoke", [bad])
