"""Write frames from a thread of their own, a few behind their producer.

`process` composites frame i on the main thread (the GL context is there) while frame i - 1 is
colour-converted and encoded on a writer thread (PyAV releases the GIL in swscale, the encoder and
the muxer), and frame i + 1 is decoded and analysed on the read-ahead thread
(:mod:`.read_ahead`): three stages on two cores. The frames reach the output in order and
unchanged, so the file is the sequential run's, byte for byte.
"""

from __future__ import annotations

import queue
import threading

_END = object()


class WriteBehind:
    """``with WriteBehind(output, depth) as w: w.write(frame)`` -- ``output.write`` is called on a
    thread of its own for each frame, in order, at most ``depth`` frames behind (``write`` blocks
    while ``depth`` frames wait). The frames must not be changed after they are handed over. An
    exception of ``output.write`` is raised by the next :meth:`write` (or when the ``with`` block
    ends); the frames after it are not written. Leaving the block waits until every frame handed
    over is written (or the writer failed); the output is not closed here."""

    def __init__(self, output, depth: int = 2):
        self.output = output
        self._queue: queue.Queue = queue.Queue(maxsize=max(int(depth), 1))
        self._error: BaseException | None = None  # the writer's exception, until raised here
        self._failed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="write-behind", daemon=True)

    def _run(self) -> None:
        while True:
            frame = self._queue.get()
            if frame is _END:
                return
            if not self._failed.is_set():
                try:
                    self.output.write(frame)
                except BaseException as exc:  # handed to the producer, raised there
                    self._error = exc
                    self._failed.set()

    def _raise(self) -> None:
        if self._error is not None:
            exc, self._error = self._error, None
            raise exc

    def write(self, frame) -> None:
        """Hand ``frame`` to the writer thread; raises the writer's exception, if it had one."""
        self._raise()
        self._queue.put(frame)

    def __enter__(self) -> WriteBehind:
        self._thread.start()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._queue.put(_END)
        self._thread.join()
        if exc_type is None:
            self._raise()
