"""Compiling the env's functions: the checks of ``compile_kwargs``, whether a C++ compiler is
there, torch.compile with ``fullgraph=True`` and, for the modes that replay CUDA graphs, the
outputs copied out of the graphs' memory."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from functools import wraps
from typing import Any

import torch

from torchpark._compat import (
    copy_all_,
    cxx_compiler_found,
    raise_recompile_limit,
    tree_flatten,
    tree_unflatten,
)
from torchpark.config import check_flag

#: ``compiler_found() -> bool``: whether inductor finds its C++ compiler here; without one a
#: compiled step fails at its first call with a long InvalidCxxCompiler traceback.
compiler_found = cxx_compiler_found

# torch.compile keeps the graphs of every compiled partial function in the cache of one
# wrapper code object, 8 by default: with three per env, the third compiled env of a process
# failed (fullgraph=True turns the limit into an error). Each env's graphs are its own.
RECOMPILE_LIMIT = 256

# torch.compile modes that replay the graph as a CUDA graph (CUDA Graph Trees).
CAPTURING_MODES = ("reduce-overhead", "max-autotune")

# torch.compile's keywords that an env may be given, with what each takes (torch's own
# signature); the env needs its step's graphs whole, so the others are not passed on.
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")


def captures(compile_kwargs: dict) -> bool:
    """Whether ``torch.compile(**compile_kwargs)`` replays its graphs as CUDA graphs."""
    return (compile_kwargs.get("mode") in CAPTURING_MODES
            or bool((compile_kwargs.get("options") or {}).get("triton.cudagraphs")))


def outputs_owned(fn: Callable) -> Callable:
    """``fn`` (a function compiled to replay as a CUDA graph) with its outputs copied out of
    the graphs' memory pool after each call: fresh tensors, filled by one foreach copy. A
    replay overwrites the outputs of the last (CUDA Graph Trees expire them), and the env
    keeps its state and hands its outputs to the caller across calls; every output copied,
    nothing the env holds lives in the pool."""

    @wraps(fn)
    def call(*args: Any) -> Any:
        torch.compiler.cudagraph_mark_step_begin()
        leaves, spec = tree_flatten(fn(*args))
        tensors = [leaf for leaf in leaves if isinstance(leaf, torch.Tensor)]
        owned = [torch.empty_like(t) for t in tensors]
        copy_all_(owned, tensors)
        copies = iter(owned)
        return tree_unflatten([next(copies) if isinstance(leaf, torch.Tensor) else leaf
                               for leaf in leaves], spec)

    return call


def compile_all(functions: Sequence[Callable], compile_kwargs: dict) -> list[Callable]:
    """Each function through ``torch.compile(fullgraph=True, **compile_kwargs)`` (any graph
    break raises), with room for every env's graphs in one process; in a mode that replays
    CUDA graphs, each call's outputs copied out of the graphs' memory."""
    raise_recompile_limit(RECOMPILE_LIMIT)
    kwargs = {"fullgraph": True, **compile_kwargs}
    compiled = [torch.compile(f, **kwargs) for f in functions]
    return [outputs_owned(f) for f in compiled] if captures(kwargs) else compiled


def check_compile_kwargs(kwargs: object) -> dict:
    """``compile_kwargs`` as a dict for ``torch.compile``, or an error naming the key that
    does not fit: ``fullgraph``, ``disable`` (bools), ``dynamic`` (a bool or None),
    ``backend`` (a name or a callable), ``mode`` (one of torch's modes or None) and
    ``options`` (a dict of inductor options by name, or None)."""
    if kwargs is None:
        return {}
    if not isinstance(kwargs, dict):
        raise TypeError(f"compile_kwargs must be a dict or None, got {kwargs!r}")
    allowed = ("fullgraph", "dynamic", "backend", "mode", "options", "disable")
    unknown = sorted(str(k) for k in kwargs if k not in allowed)
    if unknown:
        raise ValueError(f"compile_kwargs may hold {list(allowed)} (torch.compile's "
                         f"keywords), got {unknown}")
    for key in ("fullgraph", "disable"):
        if key in kwargs:
            check_flag(kwargs[key], f"compile_kwargs[{key!r}]")
    if kwargs.get("dynamic") is not None:
        check_flag(kwargs["dynamic"], "compile_kwargs['dynamic']")
    backend = kwargs.get("backend")
    if backend is not None and not (isinstance(backend, str) or callable(backend)):
        raise TypeError(f"compile_kwargs['backend'] must be a backend's name or a callable, "
                        f"got {backend!r}")
    if kwargs.get("mode") is not None and kwargs["mode"] not in COMPILE_MODES:
        raise ValueError(f"compile_kwargs['mode'] must be one of {list(COMPILE_MODES)} or "
                         f"None, got {kwargs['mode']!r}")
    options = kwargs.get("options")
    if options is not None and not (isinstance(options, dict)
                                    and all(isinstance(k, str) for k in options)):
        raise TypeError(f"compile_kwargs['options'] must be a dict of inductor options by "
                        f"name, or None, got {options!r}")
    if options is not None and kwargs.get("mode") is not None:
        raise ValueError("compile_kwargs may hold 'mode' or 'options', not both (torch.compile "
                         "takes one of them)")
    return dict(kwargs)


def compiles(caller: str) -> bool:
    """Whether torch.compile can build here (:data:`compiler_found`); where not, one
    RuntimeWarning says that ``caller`` runs eager."""
    if compiler_found():
        return True
    warnings.warn(f"{caller} runs eager: torch.compile needs a C++ compiler and none was found "
                  f"(install g++ or set CXX)", RuntimeWarning, stacklevel=3)
    return False
