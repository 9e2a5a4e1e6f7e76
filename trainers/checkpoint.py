"""Reading a checkpoint safely: tensors and plain data only (``weights_only=True``), so a
crafted file cannot run code, and a file that is not a torchpark checkpoint says so."""

from __future__ import annotations

import math
import pickle
import zipfile
from pathlib import Path

import torch
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from torchpark.config import is_integer, is_number
from trainers.config import TrainConfig, check_flags, upgraded_config

# What every checkpoint holds (evaluation needs no more); a full one, written by the
# trainer, can also be resumed from.
EVALUATION_KEYS = frozenset({"config", "frames", "actor", "obs_norm"})
RESUME_KEYS = EVALUATION_KEYS | {"critic", "optim", "env"}


def _count(value: object) -> bool:
    return is_integer(value) and value >= 0


def _seconds(value: object) -> bool:
    return is_number(value) and math.isfinite(value) and value >= 0


# The plain entries a checkpoint (or an SB3 recipe's state.pt) may hold, with what each must be.
ENTRIES = {
    "frames": (_count, "an int >= 0 (frames trained)"),
    "wall_clock_s": (_seconds, "a finite number of seconds >= 0"),
    "obs_norm": (lambda v: isinstance(v, dict), "a dict (the normaliser's state)"),
    "trained_by": (lambda v: isinstance(v, str), "a str"),
}


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else f"a {type(value).__name__}"


def load_checkpoint(path: str | Path, device: torch.device | str = "cpu",
                    required: frozenset[str] = EVALUATION_KEYS) -> dict:
    """The checkpoint at ``path``, its tensors on ``device``.

    Raises ValueError naming the path when the file is missing, is not a torch file, holds
    anything but tensors and plain data (pickled code is never run), or lacks one of
    ``required``; with ``config`` among them, when it is no dict or holds an OmegaConf
    interpolation (a config saved in older fields comes in today's,
    :func:`trainers.config.upgraded_config`).
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"checkpoint {str(path)!r} is not a file")
    try:
        checkpoint = torch.load(path, map_location=device, weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, zipfile.BadZipFile, OSError,
            ValueError, AttributeError, TypeError, KeyError, IndexError) as err:
        raise ValueError(f"checkpoint {str(path)!r} is not a torchpark checkpoint (a torch "
                         f"file of tensors and plain data): {_first_line(err)}") from None
    if not isinstance(checkpoint, dict):
        raise ValueError(f"checkpoint {str(path)!r} is not a torchpark checkpoint: it holds a "
                         f"{type(checkpoint).__name__}, not a dict")
    missing = sorted(required - set(checkpoint))
    if missing:
        raise ValueError(f"checkpoint {str(path)!r} is not a torchpark checkpoint: it lacks "
                         f"{missing}")
    for key, (fits, allowed) in ENTRIES.items():
        if key in checkpoint and not fits(checkpoint[key]):
            raise ValueError(f"checkpoint {str(path)!r}: its {key} must be {allowed}, got "
                             f"{_shown(checkpoint[key])}")
    if "config" not in required:
        return checkpoint
    if not isinstance(checkpoint["config"], dict):
        raise ValueError(f"checkpoint {str(path)!r} is not a torchpark checkpoint: its config "
                         f"is not a dict")
    interpolated = _interpolation(checkpoint["config"])
    if interpolated is not None:
        raise ValueError(f"checkpoint {str(path)!r} has an OmegaConf interpolation ('${{...}}') "
                         f"in config.{interpolated}: a saved config holds values, never "
                         f"something to resolve")
    try:
        checkpoint["config"] = upgraded_config(checkpoint["config"])
    except ValueError as err:
        raise ValueError(f"checkpoint {str(path)!r} has an invalid config: {err}") from None
    return checkpoint


def load_trained(path: str | Path) -> tuple[TrainConfig, dict]:
    """A checkpoint's training config and contents (tensors on the CPU); ValueError naming
    the path when it is not a torchpark checkpoint or its config is not a TrainConfig's."""
    checkpoint = load_checkpoint(path)
    try:
        check_flags(checkpoint["config"])
        merged = OmegaConf.merge(OmegaConf.structured(TrainConfig), checkpoint["config"])
        return OmegaConf.to_object(merged), checkpoint
    except (OmegaConfBaseException, ValueError) as err:
        raise ValueError(f"checkpoint {str(path)!r} has an invalid config: "
                         f"{str(err).splitlines()[0]}") from None


def _interpolation(config: object, name: str = "") -> str | None:
    """The dot name of the first string in a saved config that OmegaConf would resolve
    (``${...}``: an environment variable, a resolver), or None."""
    if isinstance(config, dict):
        items = config.items()
    elif isinstance(config, (list, tuple)):
        items = enumerate(config)
    else:
        return name if isinstance(config, str) and "${" in config else None
    for key, value in items:
        found = _interpolation(value, f"{name}.{key}".lstrip("."))
        if found is not None:
            return found
    return None


def load_weights(module: torch.nn.Module | torch.optim.Optimizer, state: object,
                 path: str | Path, entry: str) -> None:
    """``module.load_state_dict(state)``, the checkpoint's ``entry``; ValueError naming the
    checkpoint and the entry when the weights do not fit the module its config builds (a
    crafted or damaged file)."""
    try:
        module.load_state_dict(state)
    except (RuntimeError, ValueError, KeyError, TypeError, AttributeError, IndexError) as err:
        raise ValueError(f"checkpoint {str(path)!r}: its {entry} does not fit the network its "
                         f"config builds: {_first_line(err)}") from None


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__
