"""How much memory this process may still allocate (a leaf module: it imports nothing of spidermatch).

Every stage that could allocate more than a machine has asks here first and refuses or chunks
(the ILP's size in :mod:`spidermatch.model_size`, a restricted MIP in column generation).
"""

from __future__ import annotations

import os
import resource
from pathlib import Path

GIB = float(1 << 30)


def available_memory(share: float = 1.0) -> int | None:
    """Bytes this process may still allocate: the least of free memory, its cgroup's and RLIMIT_AS's room.

    None where none of them can be read (then nothing is refused). ``share``: the part of the
    free memory and the cgroup's room counted for this process (0.5 for each of two processes
    that allocate side by side); RLIMIT_AS is per process and counted whole.
    """
    shared = [_mem_available(), _cgroup_room()]
    limits = [None if room is None else int(share * room) for room in shared]
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        limits.append(soft - _own_address_space())
    known = [limit for limit in limits if limit is not None]
    return max(min(known), 0) if known else None


def _mem_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_room() -> int | None:
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit == "max":
            return None
        return int(limit) - int(Path("/sys/fs/cgroup/memory.current").read_text())
    except (OSError, ValueError):
        return None


def _own_address_space() -> int:
    try:
        for line in Path(f"/proc/{os.getpid()}/status").read_text().splitlines():
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0
