"""Stop signals (SIGINT, SIGTERM) that come while a node's process is still starting: importing
its networks and libraries, before :meth:`~facesculpt.runtime.node.Node.run` handles them.

Python's own SIGINT handling would end such a process by KeyboardInterrupt, without a word, and
the graph's log would miss the node's "stopping" line. ``facesculpt run`` calls
:func:`hold_stop_signals` first thing; the node's run then takes :func:`held_signal` and stops
at once, saying so, as it would for a signal that came while it ran.
"""

from __future__ import annotations

import signal
import threading

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_held: list[int] = []


def _hold(signum, frame) -> None:
    _held.append(signum)


def hold_stop_signals() -> None:
    """From now until a node installs its own handlers, remember SIGINT and SIGTERM instead of
    acting on them (only the main thread may set handlers: elsewhere this does nothing)."""
    if threading.current_thread() is threading.main_thread():
        for s in STOP_SIGNALS:
            signal.signal(s, _hold)


def held_signal() -> int | None:
    """The first stop signal held since :func:`hold_stop_signals` (None: none came); forgets them."""
    first = _held[0] if _held else None
    _held.clear()
    return first
