"""NamedTuple records (states, step results, boxes) updated inside compiled code.

``record._replace(...)`` is what one would write, but torch 2.11's ``torch.compile`` returns
its result empty (a NamedTuple of no fields) from a compiled function, so the env's compiled
step failed there; :func:`replace` builds the record through its constructor, which every
supported torch compiles.
"""

from __future__ import annotations

from typing import Any, NamedTuple, TypeVar

R = TypeVar("R", bound=NamedTuple)


def replace(record: R, **changes: Any) -> R:
    """``record`` with the fields named in ``changes`` replaced, the others kept (what
    ``record._replace(**changes)`` does); an unknown field name is a ``ValueError``."""
    unknown = changes.keys() - set(record._fields)
    if unknown:
        raise ValueError(f"{type(record).__name__} has no field {sorted(unknown)[0]!r}")
    return type(record)(*(changes.get(name, value)
                          for name, value in zip(record._fields, record, strict=True)))
