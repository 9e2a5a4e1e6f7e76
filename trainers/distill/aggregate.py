"""DAgger's aggregate: every iteration's labelled states (inputs, labels, weights), each
iteration's kept on disk (``DIR/dagger_data/``) as it is made, so that a resumed run fits the
same data."""

from __future__ import annotations

from pathlib import Path

import torch

from torchpark.files import save_torch

# The folder of a run's labelled states, one file per iteration.
DATA = "dagger_data"


def data_path(out: Path, iteration: int) -> Path:
    """Where the states labelled in ``iteration`` of the run in ``out`` are kept."""
    return out / DATA / f"iteration_{iteration:03d}.pt"


class Aggregate:
    """The labelled states of the iterations so far, in ``out``'s data folder."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.parts: list[list[torch.Tensor]] = []

    def __len__(self) -> int:
        return len(self.parts)

    def add(self, part: list[torch.Tensor]) -> None:
        """Keep the next iteration's [inputs (B, D), labels (B, 2), weights (B,)], on disk
        first (whole or not at all)."""
        path = data_path(self.out, len(self.parts))
        path.parent.mkdir(exist_ok=True)
        save_torch(part, path)
        self.parts.append(part)

    def load(self, iterations: int, device: torch.device) -> None:
        """The first ``iterations`` iterations' states, as a run saved them (plain tensors
        only: nothing loaded runs code)."""
        for k in range(len(self.parts), iterations):
            path = data_path(self.out, k)
            try:
                inputs, labels, weights = torch.load(path, map_location=device,
                                                     weights_only=True)
            except Exception as err:  # not a torch file, not plain data, or not three tensors
                raise ValueError(f"--resume: {path} is not a distiller's labelled data "
                                 f"({type(err).__name__})") from None
            self.parts.append([inputs, labels, weights])

    def missing(self, iterations: int) -> Path | None:
        """The first of the first ``iterations`` iterations' files that is missing, if any."""
        return next((data_path(self.out, k) for k in range(iterations)
                     if not data_path(self.out, k).exists()), None)

    def all(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Every state so far: inputs (S, D), labels (S, 2), weights (S,)."""
        inputs, labels, weights = (torch.cat(column) for column in zip(*self.parts,
                                                                        strict=True))
        return inputs, labels, weights
