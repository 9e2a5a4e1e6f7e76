"""Reading a checkpoint safely: tensors and plain data only (``weights_only=True``), so a
crafted file cannot run code, and a file that is not a torchpark checkpoint says so."""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import torch

# What every checkpoint holds (evaluation needs no more); a full one, written by the
# trainer, can also be resumed from.
EVALUATION_KEYS = frozenset({"config", "frames", "actor", "obs_norm"})
RESUME_KEYS = EVALUATION_KEYS | {"critic", "optim", "env"}


def load_checkpoint(path: str | Path, device: torch.device | str = "cpu",
                    required: frozenset[str] = EVALUATION_KEYS) -> dict:
    """The checkpoint at ``path``, its tensors on ``device``.

    Raises ValueError naming the path when the file is missing, is not a torch file, holds
    anything but tensors and plain data (pickled code is never run), or lacks one of
    ``required``.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"checkpoint {str(path)!r} is not a file")
    try:
        checkpoint = torch.load(path, map_location=device, weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, zipfile.BadZipFile, OSError,
            ValueError, AttributeError, TypeError) as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ValueError(f"checkpoint {str(path)!r} is not a torchpark checkpoint (a torch "
                         f"file of tensors and plain data): {first}") from None
    if not isinstance(checkpoint, dict):
        raise ValueError(f"checkpoint {str(path)!r} is not a torchpark checkpoint: it holds a "
                         f"{type(checkpoint).__name__}, not a dict")
    missing = sorted(required - set(checkpoint))
    if missing or not isinstance(checkpoint["config"], dict):
        raise ValueError(f"checkpoint {str(path)!r} is not a torchpark checkpoint: "
                         + (f"it lacks {missing}" if missing else "its config is not a dict"))
    return checkpoint
