"""How well students fit the same labelled states: each checkpoint's weighted imitation
error (the distiller's fit loss, ``trainers.distill.fit``) on each iteration of one run's
saved aggregate (``DIR/dagger_data``), and its unweighted mean.

    python research/fit_probe.py /tmp/pa_replay/dagger_data \
        results/policy_alone/checkpoint_best.pt /tmp/pa_replay/checkpoint_best.pt

Iteration 0 holds the first rollouts' states and, after them, the final-approach states
(the last ``approach_states`` rows, ``dagger.csv``); those are printed apart.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from tensordict import TensorDict

from trainers.agent import TrainedAgent, load_agent
from trainers.distill.labels import STUDENT_INPUT
from trainers.heads import BinnedGearHead, imitation_error
from trainers.utils import NORMALISED


def errors(agent: TrainedAgent, inputs: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """The agent's per-state imitation error (N,) on ``inputs``, ``labels``."""
    norm = agent._inputs.transform[-1].to_observation_norm()
    net = agent.actor.module[0]
    body = net.module[0]
    out = []
    with torch.no_grad():
        for x, y in zip(inputs.split(65536), labels.split(65536), strict=True):
            td = norm(TensorDict({STUDENT_INPUT: x}, [x.shape[0]]))
            if isinstance(body, BinnedGearHead):
                out.append(body.imitation_error(td[NORMALISED], y))
            else:
                out.append(imitation_error(torch.tanh(net(td)["loc"]), y))
    return torch.cat(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--approach", type=int, default=195_825,
                        help="final-approach states at the end of iteration 0")
    args = parser.parse_args()
    parts = sorted(args.data.glob("iteration_*.pt"))
    agents = [load_agent(c) for c in args.checkpoints]
    print("part," + ",".join(f"{Path(c).parent.name}_weighted,{Path(c).parent.name}_mean"
                             for c in args.checkpoints))
    for k, part in enumerate(parts):
        x, y, w = torch.load(part, weights_only=True)
        pieces = [("rollouts", slice(0, x.shape[0] - args.approach)),
                  ("approach", slice(x.shape[0] - args.approach, None))] if k == 0 else [
                      ("rollouts", slice(None))]
        per = [errors(a, x, y) for a in agents]
        for name, rows in pieces:
            cells = [f"{(e[rows] * w[rows]).mean():.4f},{e[rows].mean():.4f}" for e in per]
            print(f"{k}:{name}," + ",".join(cells), flush=True)


if __name__ == "__main__":
    main()
