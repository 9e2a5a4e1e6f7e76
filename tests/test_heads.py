"""The binned steering (trainers.heads.BinnedGearHead): the action is the likeliest bin's
centre plus its offset, the actor's deterministic action is that action, and a fit keeps one
of two angles that the same input is labelled with where a regression averages them; PPO and a
student without the gear head refuse it by name."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type

from trainers.config import check_agent, load_config, replace
from trainers.distill.config import load_distill_config
from trainers.heads import BinnedGearHead, imitation_error
from trainers.utils import make_ppo_models


def test_the_steering_is_the_likeliest_bins_centre_plus_its_offset():
    bins = 5  # centres -1, -0.5, 0, 0.5, 1; offsets within 0.25
    head = BinnedGearHead(nn.Identity(), bins, scale_outputs=True)
    out = torch.zeros(2, BinnedGearHead.out_features(bins))
    out[:, 0] = torch.tensor([2.0, -3.0])  # the gear
    out[:, 1] = 0.5  # forward speed
    out[0, 2 + 3] = 4.0  # forward: bin 3 (0.5) ...
    out[0, 2 + bins + 3] = 0.5  # ... offset 0.25 tanh(0.5)
    out[0, 2 + bins + 1] = 3.0  # another bin's offset: not read
    out[1, 2 + 0] = 1.0  # bin 0 (-1), offset -0.25 tanh(1): clamped at -1
    out[1, 2 + bins] = -1.0
    rev = 1 + 1 + 2 * bins
    out[:, rev] = -0.2  # reverse speed
    out[:, rev + 1 + 4] = 1.0  # reverse: bin 4 (1), offset 0
    u = head.action(out)
    expected = torch.tensor([
        [torch.tanh(torch.tensor(2.0)), torch.tanh(torch.tensor(0.5)),
         0.5 + 0.25 * torch.tanh(torch.tensor(0.5)), torch.tanh(torch.tensor(-0.2)), 1.0],
        [torch.tanh(torch.tensor(-3.0)), torch.tanh(torch.tensor(0.5)), -1.0,
         torch.tanh(torch.tensor(-0.2)), 1.0]])
    assert torch.allclose(u, expected, atol=1e-6)
    loc_scale = head(out)
    assert loc_scale.shape == (2, 10) and torch.equal(loc_scale[:, 5:], torch.zeros(2, 5))
    assert torch.allclose(torch.tanh(loc_scale[:, :5]), u, atol=1e-6)


@pytest.mark.parametrize("bins", [0, 1, 4])
def test_bins_that_centre_none_on_straight_ahead_are_refused(bins):
    with pytest.raises(ValueError, match="bins must be an odd int >= 3"):
        BinnedGearHead(nn.Identity(), bins, scale_outputs=False)


def test_the_actors_deterministic_action_is_the_heads():
    cfg = load_config("smoke", ["agent.action_exponents=[3.0,1.0]", "agent.gear_head=true"])
    spec = Bounded(-torch.ones(5), torch.ones(5), shape=(5,))
    model = replace(cfg.model, steer_bins=9, state_dependent_std=True, hidden=[16])
    actor, _ = make_ppo_models(6, spec, model)
    z = torch.randn(32, 6, generator=torch.Generator().manual_seed(0)) * 3
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        action = actor(TensorDict({"observation_norm": z}, [32]))["action"]
    head = actor.module[0].module[0]
    assert isinstance(head, BinnedGearHead)
    assert torch.allclose(action, head.action(z), atol=1e-5)


def fitted_steer(binned: bool) -> float:
    """One input labelled full lock left in 3 of 5 states and full lock right in 2 (the
    planner's choice flipping between look-alike states): the fitted steering there."""
    torch.manual_seed(0)
    z = torch.ones(5, 4)
    label = torch.tensor([[0.5, -1.0]] * 3 + [[0.5, 1.0]] * 2)
    trunk = nn.Sequential(nn.Linear(4, 32), nn.Tanh(),
                          nn.Linear(32, BinnedGearHead.out_features(9) if binned else 5))
    head = BinnedGearHead(trunk, 9, scale_outputs=False) if binned else trunk
    optim = torch.optim.Adam(head.parameters(), lr=1e-2)
    for _ in range(400):
        if binned:
            loss = head.imitation_error(z, label).mean()
        else:
            loss = imitation_error(torch.tanh(head(z)), label).mean()
        optim.zero_grad()
        loss.backward()
        optim.step()
    with torch.no_grad():
        u = head.action(z[:1]) if binned else torch.tanh(head(z[:1]))
    return u[0, 2].item()


@pytest.mark.slow
def test_a_fit_keeps_the_likelier_of_two_angles_where_a_regression_averages_them():
    assert fitted_steer(binned=True) == pytest.approx(-1.0, abs=1e-3)
    assert fitted_steer(binned=False) == pytest.approx(-0.2, abs=0.05)


def test_ppo_and_a_student_without_the_gear_head_refuse_the_bins_by_name():
    with pytest.raises(ValueError, match=r"model\.steer_bins"):
        load_config("smoke", ["model.steer_bins=9"])
    with pytest.raises(ValueError, match=r"^student\.model\.steer_bins"):
        load_distill_config("smoke", ["student.model.steer_bins=4"])
    cfg = load_config("smoke")
    with pytest.raises(ValueError, match=r"model\.steer_bins"):
        check_agent(replace(cfg, model=replace(cfg.model, steer_bins=9)))
