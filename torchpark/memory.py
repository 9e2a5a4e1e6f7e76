"""Sizes checked before they are allocated: what a device has free, and a one-line refusal
when a size a user asked for would not fit.

Every size a user gives torchpark (the number of lots, the episodes drawn ahead, a grid of
pictures) is either bounded by a constant or estimated here and refused before anything is
allocated, so that a mistyped ``--num-envs 10000000`` is one line naming the argument, not an
allocator's traceback or a machine swapping.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch


class TooLarge(ValueError):
    """A size whose memory the device does not have: one line naming it."""


def _cgroup_free() -> int | None:
    """What this process's memory cgroup still allows, bytes (v2, else v1); None if
    unlimited or unknown."""
    for limit, used in (("memory.max", "memory.current"),
                        ("memory/memory.limit_in_bytes", "memory/memory.usage_in_bytes")):
        try:
            cap = Path("/sys/fs/cgroup", limit).read_text().strip()
            now = int(Path("/sys/fs/cgroup", used).read_text())
        except (OSError, ValueError):
            continue
        if cap.isdigit() and int(cap) < 2**60:
            return max(int(cap) - now, 0)
    return None


def free_bytes(device: torch.device) -> int | None:
    """Memory ``device`` can still give, bytes: CUDA's free memory, or the host's available
    memory (``MemAvailable``, within the process's cgroup limit); None where unknown."""
    if device.type == "cuda":
        return int(torch.cuda.mem_get_info(device)[0])
    try:
        meminfo = Path("/proc/meminfo").read_text()
        host = int(next(line.split()[1] for line in meminfo.splitlines()
                        if line.startswith("MemAvailable:"))) * 1024
    except (OSError, StopIteration, ValueError, IndexError):
        try:
            host = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return None
    limit = _cgroup_free()
    return host if limit is None else min(host, limit)


def check_fits(needed: int, what: str, device: torch.device) -> None:
    """:class:`TooLarge` naming ``what`` (e.g. ``"num_envs=1000000"``) when ``needed`` bytes
    exceed what ``device`` has free (nothing is checked where that is unknown)."""
    free = free_bytes(device)
    if free is not None and needed > free:
        raise TooLarge(f"{what} needs about {needed / 2**30:.1f} GiB on {device}, which has "
                       f"{free / 2**30:.1f} GiB free: ask for less")
