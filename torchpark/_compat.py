"""Every private torch / torchrl name torchpark touches, each behind one function with why the
public API does not serve. Checked on torch 2.13.0 and torchrl 0.14.1 (what CI installs), and
on torch 2.14.1 and 2.15.0, where every name here works (research/experiments.md, "the version
pins tried"); moving the version pins in ``pyproject.toml`` is this file's work.

The torchrl hooks our subclasses override must be methods of those classes, so they are only
named here: ``EnvBase._step_and_maybe_reset`` (:class:`torchpark.ParkingEnv`,
:class:`torchpark.transforms.sync_free.SyncFreeEnv`), ``Transform._reset_env_preprocess`` and
``Transform._inv_call`` (:mod:`torchpark.curriculum`), and ``VecNormV2._maybe_stateful_init``
(:class:`~torchpark.transforms.sync_free.SyncFreeVecNorm`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase

# torch's pytree, the one torch.compile traces: ``torch.utils._pytree`` (torch's public
# ``torch.utils.pytree`` does not exist in torch 2.13; optree is another package).
from torch.utils._pytree import tree_flatten, tree_map_only, tree_unflatten
from torchrl.envs import EnvBase, Transform

__all__ = ["collector_carrier", "copy_all_", "cxx_compiler_found", "post_step_mdp_hooks",
           "raise_recompile_limit", "reset_env_preprocess", "step_mdp", "transform_reset",
           "tree_flatten", "tree_map_only", "tree_unflatten"]


def raise_recompile_limit(limit: int) -> None:
    """At least ``limit`` graphs per compiled code object (and 4x that in all), never lower.

    torch.compile keeps every graph of a wrapper's code object under one limit (8 by
    default) that ``fullgraph=True`` turns into an error; ``torch._dynamo.config`` is its
    only setting (no ``torch.compiler`` equivalent as of torch 2.13)."""
    config = torch._dynamo.config
    config.recompile_limit = max(config.recompile_limit, limit)
    config.accumulated_recompile_limit = max(config.accumulated_recompile_limit, 4 * limit)


def copy_all_(destinations: Sequence[torch.Tensor], sources: Sequence[torch.Tensor]) -> None:
    """``destinations[i].copy_(sources[i])`` for every i in one call.

    ``torch._foreach_copy_``: one kernel launch for all the tensors where a loop of
    ``copy_`` launches one each (torch has no public foreach copy)."""
    torch._foreach_copy_(list(destinations), list(sources))


def cxx_compiler_found() -> bool:
    """Whether inductor finds the C++ compiler it builds CPU kernels with (``CXX``, else g++
    or clang++ on the path).

    ``torch._inductor.cpp_builder.get_cpp_compiler`` is inductor's own search, so the answer
    is the one a compile would get; torch has no public query. Guarded: an API that moved
    answers False (compile nothing) rather than failing."""
    try:
        from torch._inductor import cpp_builder

        cpp_builder.get_cpp_compiler()
    except Exception:  # InvalidCxxCompiler, or the API moved
        return False
    return True


def step_mdp(env: EnvBase, tensordict: TensorDictBase) -> TensorDictBase:
    """The root of the next step from a stepped ``tensordict`` (``"next"`` moved up), with
    the env's own key lists: ``EnvBase._step_mdp``, the function torchrl's own
    ``step_and_maybe_reset`` calls (the public ``torchrl.envs.utils.step_mdp`` rebuilds the
    key lists each call)."""
    return env._step_mdp(tensordict)


def post_step_mdp_hooks(env: EnvBase) -> Callable | None:
    """The env's ``_post_step_mdp_hooks`` (a transform's hook between the step and the
    reset; None where there is none), which torchrl's ``step_and_maybe_reset`` applies and a
    replacement of it must apply too."""
    return env._post_step_mdp_hooks


def reset_env_preprocess(transform: Transform, tensordict: TensorDictBase) -> TensorDictBase:
    """``Transform._reset_env_preprocess``: what a transform does to the reset request before
    the env below sees it, as torchrl's ``TransformedEnv._reset`` calls it."""
    return transform._reset_env_preprocess(tensordict)


def transform_reset(transform: Transform, tensordict: TensorDictBase,
                    tensordict_reset: TensorDictBase) -> TensorDictBase:
    """``Transform._reset``: a transform's part of a reset (its statistics, its outputs in
    the reset's tensordict), as ``TransformedEnv._reset`` calls it after the base env's."""
    return transform._reset(tensordict, tensordict_reset)


def collector_carrier(collector: Any) -> TensorDictBase:
    """The tensordict a collector carries from one batch to the next (the envs' last step,
    the policy's recurrent state): ``collector._carrier``, which torchrl 0.14 saves in no
    ``state_dict``."""
    return collector._carrier
