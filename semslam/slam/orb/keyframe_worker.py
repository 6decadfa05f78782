"""Keyframe consumers (ORB-SLAM's local mapping and loop closing share this shape): a
``KeyframeInbox`` of waiting keyframes and a ``KeyframeWorker`` that drains it in its own
thread, or processes each keyframe inline when it was never started (``--sequential``).

Waiting is on a condition variable, never polling: ``wait_idle`` wakes when the worker has
nothing queued and nothing in hand, or when its thread has ended.  ``paused`` is ORB-SLAM's
RequestStop / Release: the worker finishes the keyframe in hand and takes no other until the
block ends (loop closing pauses local mapping while it changes the map).
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Protocol

from semslam.runtime import lower_thread_priority
from semslam.slam.orb.map import KeyFrame

log = logging.getLogger(__name__)


class KeyframeSink(Protocol):
    """Where tracking (or local mapping) hands a finished keyframe on."""

    def insert(self, kf: KeyFrame) -> None: ...

    def idle(self) -> bool: ...

    def queue_size(self) -> int: ...


class KeyframeInbox:
    """Keyframes waiting for one worker and whether it is busy, under one condition.

    Shared read-only with others that must wait for the worker (loop closing waits for
    local mapping to go idle before it corrects a loop, as ORB-SLAM's RequestStop does).
    """

    def __init__(self) -> None:
        self._items: deque[KeyFrame] = deque()
        self._cond = threading.Condition()
        self._busy = False
        self._closed = False
        self._in_hand = False  # the worker took a keyframe and has not called done()
        self._pauses = 0

    def put(self, kf: KeyFrame) -> None:
        with self._cond:
            self._items.append(kf)
            self._busy = True
            self._cond.notify_all()

    def take(self) -> KeyFrame | None:
        """The next keyframe (not while paused); None once closed and drained."""
        with self._cond:
            self._cond.wait_for(lambda: not self._pauses and (self._items or self._closed))
            if not self._items:
                return None
            self._in_hand = True
            return self._items.popleft()

    def done(self) -> None:
        """The worker finished a keyframe; idle if nothing else is queued."""
        with self._cond:
            self._in_hand = False
            if not self._items:
                self._busy = False
            self._cond.notify_all()

    @contextmanager
    def paused(self, timeout: float | None = 60.0) -> Iterator[bool]:
        """Within the block the worker holds no keyframe and takes none (it finishes the one
        in hand first); yields False if that did not happen within ``timeout``."""
        with self._cond:
            self._pauses += 1
            try:
                ok = self._cond.wait_for(lambda: not self._in_hand, timeout)
            except BaseException:
                self._pauses -= 1
                raise
        try:
            yield ok
        finally:
            with self._cond:
                self._pauses -= 1
                self._cond.notify_all()

    def close(self, discard: bool = False) -> None:
        """No more keyframes: the worker finishes the queued ones (or drops them) and ends."""
        with self._cond:
            self._closed = True
            if discard:
                self._items.clear()
                self._busy = False
            self._cond.notify_all()

    def idle(self) -> bool:
        with self._cond:
            return not self._busy and not self._items

    def queue_size(self) -> int:
        with self._cond:
            return len(self._items)

    def has_pending(self) -> bool:
        """More keyframes are waiting (local mapping then skips BA, as ORB-SLAM does)."""
        return self.queue_size() > 0

    def wait_idle(self, timeout: float | None = 60.0) -> bool:
        """Block until the worker is idle (or closed and discarded); False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._busy and not self._items, timeout)


class KeyframeWorker:
    """Processes keyframes from its inbox: in its own thread after ``start()``, else inline."""

    thread_name = "keyframe-worker"

    def __init__(self, inbox: KeyframeInbox) -> None:
        self.inbox = inbox
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    def process(self, kf: KeyFrame) -> None:
        raise NotImplementedError

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=self.thread_name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        lower_thread_priority()  # tracking's frame comes first on a busy machine
        while (kf := self.inbox.take()) is not None:
            try:
                self.process(kf)
            except BaseException as exc:  # surfaced by the system on the next frame and at shutdown
                log.exception("%s failed", self.thread_name)
                self.error = exc
                self.inbox.close(discard=True)
                return
            finally:
                self.inbox.done()

    def insert(self, kf: KeyFrame) -> None:
        if self._thread is None:
            self.process(kf)
        else:
            self.inbox.put(kf)

    def idle(self) -> bool:
        return self.inbox.idle()

    def queue_size(self) -> int:
        return self.inbox.queue_size()

    def stop(self, discard: bool = False) -> None:
        """Finish the queued keyframes (or drop them), then end the thread."""
        if self._thread is not None:
            self.inbox.close(discard=discard)
            self._thread.join()
            self._thread = None
