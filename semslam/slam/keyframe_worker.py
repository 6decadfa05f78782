"""A keyframe consumer that runs in its own thread, or inline when started without one
(ORB-SLAM's local mapping and loop closing share this shape)."""

from __future__ import annotations

import logging
import queue
import threading
import time

from semslam.slam.map import KeyFrame

log = logging.getLogger(__name__)


class KeyframeWorker:
    """``insert(kf)`` queues a keyframe for ``process`` (inline until ``start()``)."""

    thread_name = "keyframe-worker"

    def __init__(self) -> None:
        self.queue: "queue.Queue[KeyFrame | None]" = queue.Queue()
        self._thread: threading.Thread | None = None
        self._busy = threading.Event()
        self.error: BaseException | None = None

    def process(self, kf: KeyFrame) -> None:
        raise NotImplementedError

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=self.thread_name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            kf = self.queue.get()
            if kf is None:
                return
            self._busy.set()
            try:
                self.process(kf)
            except BaseException as exc:  # surfaced by the System on the next frame
                log.exception("%s failed", self.thread_name)
                self.error = exc
                return
            finally:
                if self.queue.empty():
                    self._busy.clear()

    def insert(self, kf: KeyFrame) -> None:
        if self._thread is None:
            self.process(kf)
        else:
            self._busy.set()
            self.queue.put(kf)

    def idle(self) -> bool:
        return not self._busy.is_set() and self.queue.empty()

    def queue_size(self) -> int:
        return self.queue.qsize()

    def wait_idle(self, timeout: float = 60.0) -> None:
        end = time.time() + timeout
        while not self.idle() and time.time() < end and self._thread is not None and self._thread.is_alive():
            time.sleep(0.002)

    def stop(self) -> None:
        """Finish the queued keyframes, then end the thread."""
        if self._thread is not None:
            self.queue.put(None)
            self._thread.join()
            self._thread = None
