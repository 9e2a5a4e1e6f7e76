"""The distilled student's gear-head errors: :func:`imitation_error`, the regression of its
five actions on the teacher's labels, and the binned steering (``ModelConfig.steer_bins``),
a gear-head policy whose steering is a choice among bins, not a regression.

The teacher's planner steers at five fixed angles (0, half and full lock either way) and
switches between them from one state to the next; a squared-error fit of one tanh output
averages the angles where the states look alike, and the student turns on a wider circle
than the teacher at every turn-in. Here each gear's steering is a classification over
``bins`` centres evenly spanning [-1, 1] (the planner's five angles among them when
``bins - 1`` is a multiple of 4) with an offset within the chosen bin for the docking law's
fine steering; research/experiments.md, "binned steering", says what it did.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

# The fit's weights of the bins' cross-entropy and of the offset's squared error (in units
# of half a bin) against the gear's and the speed's squared errors (of u in [-1, 1]).
CLASS_WEIGHT = 0.1
OFFSET_WEIGHT = 0.1
# atanh of the action's bounds would be infinite: the loc stops this short of them.
EDGE = 1e-6


def imitation_error(u: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
    """The squared error (N,) of the student's actions u against the teacher's labels (N, 2)
    (speed, steer), all in [-1, 1]: the gear head's u (N, 5)
    (:func:`~torchpark.transforms.actions.gear_select`) on its gear against the label's (+1 where
    the label's speed >= 0, else -1) and on that gear's pair only against (|speed|, steer):
    the other gear's pair is not pulled toward an answer it never gives."""
    forward = label[:, 0] >= 0
    speed = torch.where(forward, u[:, 1], u[:, 3])
    steer = torch.where(forward, u[:, 2], u[:, 4])
    return ((u[:, 0] - torch.where(forward, 1.0, -1.0)).pow(2)
            + (speed - label[:, 0].abs()).pow(2) + (steer - label[:, 1]).pow(2))


class BinnedGearHead(nn.Module):
    """The gear head's five actions u in [-1, 1] (gear, forward speed, forward steer,
    reverse speed, reverse steer; :class:`torchpark.GearActionMap`) from ``trunk``, whose
    (..., 1 + 2 (1 + 2 bins)) outputs are the gear, then per gear (forward, reverse) the
    speed, the bins' logits and each bin's offset. A gear's steering is the centre of its
    most likely bin plus that bin's offset (within half a bin); the gear and the speeds are
    tanh of their outputs.

    ``forward`` returns what the actor's TanhNormal reads: atanh(u) as its loc (5 columns),
    followed by 5 zeros where ``scale_outputs`` (the state-dependent scale's input, the
    policy's initial std everywhere)."""

    def __init__(self, trunk: nn.Module, bins: int, scale_outputs: bool) -> None:
        super().__init__()
        if bins < 3 or bins % 2 == 0:
            raise ValueError(f"bins must be an odd int >= 3 (a bin centred on 0), got {bins}")
        self.trunk, self.bins, self.scale_outputs = trunk, bins, scale_outputs
        self.register_buffer("centres", torch.linspace(-1.0, 1.0, bins), persistent=False)
        self.half = 1.0 / (bins - 1)

    @staticmethod
    def out_features(bins: int) -> int:
        """The trunk's outputs for ``bins`` bins."""
        return 1 + 2 * (1 + 2 * bins)

    def _parts(self, z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The gear's output (..., 1) and each gear's (speed, logits, offsets) (..., 1 + 2
        bins), forward then reverse."""
        out = self.trunk(z)
        width = 1 + 2 * self.bins
        return out[..., :1], out[..., 1:1 + width], out[..., 1 + width:]

    def _steer(self, part: Tensor) -> Tensor:
        """The steering (...,) of one gear's outputs: its likeliest bin's centre + offset."""
        k = part[..., 1:1 + self.bins].argmax(-1, keepdim=True)
        offset = torch.tanh(part[..., 1 + self.bins:]).gather(-1, k)[..., 0] * self.half
        return (self.centres[k[..., 0]] + offset).clamp(-1.0, 1.0)

    def action(self, z: Tensor) -> Tensor:
        """The five actions u (..., 5) in [-1, 1] at the normalised input ``z``."""
        gear, forward, reverse = self._parts(z)
        return torch.cat([torch.tanh(gear), torch.tanh(forward[..., :1]),
                          self._steer(forward)[..., None], torch.tanh(reverse[..., :1]),
                          self._steer(reverse)[..., None]], -1)

    def forward(self, z: Tensor) -> Tensor:
        loc = torch.atanh(self.action(z).clamp(-1.0 + EDGE, 1.0 - EDGE))
        return torch.cat([loc, torch.zeros_like(loc)], -1) if self.scale_outputs else loc

    def label_bin(self, steer: Tensor) -> Tensor:
        """The bin (N,) int64 whose centre is nearest each steering ``steer`` (N,) in
        [-1, 1]."""
        return ((steer + 1.0) / (2.0 * self.half)).round().long().clamp(0, self.bins - 1)

    def imitation_error(self, z: Tensor, label: Tensor) -> Tensor:
        """The fit's error (N,) at inputs ``z`` (N, D) against the teacher's labels (N, 2)
        (speed, steer) in [-1, 1]: :func:`imitation_error`'s gear and speed terms and, for the
        label's gear only, the cross-entropy of the bins against the bin nearest the label's
        steering and the squared error of that bin's centre + offset against it, in half-bin
        units (:data:`CLASS_WEIGHT`, :data:`OFFSET_WEIGHT`)."""
        gear, forward, reverse = self._parts(z)
        steer = label[:, 1]
        # the steering columns at the label: imitation_error scores the gear and the speed
        u = torch.stack((torch.tanh(gear[:, 0]), torch.tanh(forward[:, 0]), steer,
                         torch.tanh(reverse[:, 0]), steer), -1)
        part = torch.where((label[:, 0] >= 0)[:, None], forward, reverse)
        k = self.label_bin(steer)
        logits, offsets = part[:, 1:1 + self.bins], part[:, 1 + self.bins:]
        offset = torch.tanh(offsets).gather(-1, k[:, None])[:, 0] * self.half
        return (imitation_error(u, label)
                + CLASS_WEIGHT * nn.functional.cross_entropy(logits, k, reduction="none")
                + OFFSET_WEIGHT * (self.centres[k] + offset - steer).pow(2) / self.half ** 2)
