"""Competing CPU load for `facesculpt bench --load N`: N busy loops in processes of their own, as a
browser or a video call keeps a core busy on a user's laptop, so anyone can reproduce how the graph
degrades beside them."""

from __future__ import annotations

import subprocess
import sys
from contextlib import contextmanager

#: A loop that never sleeps: one core's worth of demand per process.
BUSY_LOOP = "while True:\n    pass\n"


@contextmanager
def competing_load(processes: int):
    """Run ``processes`` busy-loop processes while the block runs; they are killed when it ends
    (also on an error). Yields their pids."""
    procs = [subprocess.Popen([sys.executable, "-c", BUSY_LOOP], stdin=subprocess.DEVNULL,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for _ in range(int(processes))]
    try:
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()
