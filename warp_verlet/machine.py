"""What this machine has free, asked without importing anything heavy: the host memory available, and how a
size in bytes reads in a message. The scene loader (mesh welding) and the simulator's memory check both ask."""

from __future__ import annotations

import os


def available_host_bytes() -> int | None:
    """MemAvailable from /proc/meminfo (what can be allocated without swapping), else None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def gib(n: float) -> str:
    """``n`` bytes in GiB, for a message."""
    return f"{n / (1 << 30):.2f} GiB"
