"""Run an iterator in a thread of its own, a few items ahead of its consumer.

`process` analyses frame i + 1 (decode, landmarks, fit: onnxruntime, OpenCV and numpy release the
GIL) while the main thread composites and encodes frame i (the GL context belongs to the main
thread). The items come out in order and each is made by the same code as without the thread, so
the output does not change; only the two stages overlap on two cores.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator

_END = object()


class ReadAhead:
    """``with ReadAhead(items, depth) as it: for x in it: ...`` — ``items`` is consumed by a
    daemon thread, at most ``depth`` items ahead. An exception in the thread is raised to the
    consumer at the item where it happened; leaving the ``with`` stops the thread."""

    def __init__(self, items: Iterable, depth: int = 2):
        self._items = items
        self._queue: queue.Queue = queue.Queue(maxsize=max(int(depth), 1))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="read-ahead", daemon=True)

    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        try:
            for item in self._items:
                if not self._put((item, None)):
                    return
        except BaseException as exc:  # handed to the consumer, raised there
            self._put((_END, exc))
            return
        self._put((_END, None))

    def __enter__(self) -> Iterator:
        self._thread.start()
        return self._iterate()

    def _iterate(self) -> Iterator:
        while True:
            item, exc = self._queue.get()
            if exc is not None:
                raise exc
            if item is _END:
                return
            yield item

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
