"""PPO's clipped loss with an imitation term toward a fixed actor near the goal: how a
policy started from a distilled student (``trainers.ppo --init``) is fine-tuned in the
paper's env without unlearning what the teacher showed it at the slot."""

from __future__ import annotations

import contextlib

import torch
from tensordict import TensorDictBase
from torchrl.modules import ProbabilisticActor
from torchrl.objectives import ClipPPOLoss

from trainers.utils import NORMALISED


class AnchoredPPOLoss(ClipPPOLoss):
    """``ClipPPOLoss`` plus ``loss_anchor``: ``coef`` x the mean over a minibatch of the
    squared distance (summed over the action's dimensions, in [-1, 1] units) between the
    actor's deterministic action (tanh of its loc) and ``anchor``'s, counted in the states
    whose goal is within ``reach`` m (the raw observation's first two entries: the goal
    minus the pose, m) and zero elsewhere. ``anchor``: a frozen copy of the actor (the
    same architecture), kept out of the loss's parameters so nothing trains it."""

    def __init__(self, actor: ProbabilisticActor, critic, anchor: ProbabilisticActor,
                 coef: float, reach: float, **kwargs) -> None:
        super().__init__(actor, critic, **kwargs)
        self.coef, self.reach = coef, reach
        self._anchor = (anchor.requires_grad_(False),)  # a tuple: not a submodule

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        out = super().forward(tensordict)
        inputs = tensordict.select(NORMALISED)
        with (self.actor_network_params.to_module(self.actor_network,
                                                  preserve_module_state=False)
              if self.functional else contextlib.nullcontext()):
            loc = self.actor_network.module[0](inputs.clone(False))["loc"]
        with torch.no_grad():
            target = self._anchor[0].module[0](inputs.clone(False))["loc"]
        near = tensordict["observation"][..., :2].norm(dim=-1) < self.reach
        error = (loc.tanh() - target.tanh()).pow(2).sum(-1)
        out.set("loss_anchor", self.coef * torch.where(near, error, 0.0).mean())
        return out
