"""A lock for state that garbage-collector finalizers change too: the native registry's and the dispatcher's.

A finalizer runs wherever the collector does, and the collector runs where Python allocates: also inside a
block that holds the lock and is itself changing that state, in the same thread. A plain lock then
deadlocks (making an env again after detaching another could hang in ``attach``); a reentrant one lets the
finalizer change the state under the block's feet. :class:`DeferredLock` queues the finalizer's work instead
(:meth:`DeferredLock.defer`) and the outermost block does it at its end (the ``flush`` of
:meth:`DeferredLock.changing`). Plain Python: nothing here is compiled.
"""

from __future__ import annotations

import contextlib
import threading


class DeferredLock:
    """A reentrant lock (``lock``), a count of the changes under way and the work finalizers queued (``queue``)."""

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.queue: list = []
        self._busy = 0

    @contextlib.contextmanager
    def changing(self, flush):
        """The lock for a change; at the end of the outermost block (still holding the lock) ``flush()``, which
        does what ``queue`` holds and empties it."""
        with self.lock:
            self._busy += 1
            try:
                yield
            finally:
                self._busy -= 1
            if not self._busy:
                flush()

    def defer(self, item) -> bool:
        """Queue ``item`` when a change is under way (True: a finalizer inside a block of this thread); False
        when none is: the caller does the work now, under :meth:`changing`."""
        with self.lock:
            if self._busy:
                self.queue.append(item)
                return True
            return False
