"""Write frames on a background thread, so the simulation of frame f + 1 overlaps the writing of frame f.

The step loop hands over each frame's host copy and goes on stepping. On CUDA the next frame's graph runs
while this thread writes the frame (writer_registry.CacheWriter.write_frame); on the CPU, Warp's kernels run
in native code that releases the GIL, so the writer gets the second core. The queue is bounded (``depth``
frames): a writer slower than the simulation makes the step loop wait instead of holding an unbounded number
of frames in memory.

Errors in the writer thread are raised again in the step loop at its next ``submit`` or at ``close``. Only
this thread touches the writer (a USD stage, which is not thread-safe) between the first ``submit`` and
``close``, so no two threads use it at once.
"""

from __future__ import annotations

import queue
import threading
from typing import Any, Callable

_STOP = object()


class BackgroundWriter:
    def __init__(self, write: Callable[..., None], depth: int = 2):
        self._write = write
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None
        self._reported = False
        self._thread = threading.Thread(target=self._run, name="cache-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            if self._error is None:  # after a failure, drain without writing so the producer never blocks
                try:
                    self._write(*item)
                except BaseException as exc:  # re-raised in the step loop
                    self._error = exc

    def submit(self, *args: Any) -> None:
        """Queue one call of ``write(*args)``; waits while ``depth`` calls are already queued."""
        self._raise_if_failed()
        self._queue.put(args)

    def close(self) -> None:
        """Write what is queued, stop the thread, and raise the writer's error if it had one."""
        if self._thread.is_alive():
            self._queue.put(_STOP)
            self._thread.join()
        self._raise_if_failed()

    def _raise_if_failed(self) -> None:
        if self._error is not None and not self._reported:
            self._reported = True  # once: close() after a failed submit must not raise it a second time
            raise self._error
