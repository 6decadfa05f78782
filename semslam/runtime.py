"""Process-wide settings for running SLAM on a few cores, applied by entry points.

SLAM runs its own threads (tracking, local mapping, loop closing) and a BA worker
process; BLAS and OpenCV worker pools on top of them only compete for the cores
(measured on 2 cores: 36 -> 28 ms/frame median on room_loop). Nothing here acts at import:
the CLI's ``main`` and the benchmark scripts call ``limit_threads()`` first thing (BLAS
reads its variables when numpy loads), a library user decides for their own process, and
a Ray worker gets what its task sets. The environment overrides the defaults.
"""

from __future__ import annotations

import os

BLAS_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


#: The interpreter's thread switch interval (seconds). Tracking's compiled kernels and
#: OpenCV calls release the GIL; each time one returns, tracking waits for the thread that
#: took the GIL (local mapping, mostly Python) to hand it back, up to one interval. Measured
#: on 2 cores with a Python thread busy beside it (benchmarks/gil_handoff.py):
#: ORB extraction 6.0 ms alone, 24.1 ms median at CPython's default 5 ms, 13.4 ms at 1 ms
#: (0.2 ms: 16.4 ms, the switches themselves cost).
SWITCH_INTERVAL_S = float(os.environ.get("SEMSLAM_SWITCH_INTERVAL", "0.001"))


def limit_threads() -> None:
    """One BLAS thread (for libraries not yet loaded) and one OpenCV thread, unless the
    environment (``*_NUM_THREADS``, ``SEMSLAM_OPENCV_THREADS``) says otherwise; the
    interpreter's switch interval set to ``SWITCH_INTERVAL_S``."""
    import sys

    for var in BLAS_VARIABLES:
        os.environ.setdefault(var, "1")
    import cv2

    cv2.setNumThreads(int(os.environ.get("SEMSLAM_OPENCV_THREADS", "1")))
    sys.setswitchinterval(SWITCH_INTERVAL_S)


#: Niceness added to the threads and the process that tracking does not wait for (local
#: mapping, loop closing, the BA worker): on 2 cores they then take the CPU when tracking
#: and the semantic thread leave it, instead of delaying the current frame. Measured on a
#: quiet 2-core machine (300 frames, threaded, switch interval 1 ms, 2 runs each): `orb`
#: on walking_xyz 34-39 -> 20-21 ms median, `default` 31 -> 27-30 ms; static_xyz within
#: run-to-run noise. 0 turns it off.
BACKGROUND_NICE = int(os.environ.get("SEMSLAM_BACKGROUND_NICE", "5"))
#: The semantic thread takes it too when tracking never waits for it (``semantics.schedule:
#: latest``, the ``default`` preset); with ``every`` it keeps its priority (niced, it made no
#: difference there). So does the reader (``pipeline.prefetch``), which decodes up to two
#: frames ahead: as fast as frames decode, its PNG decoding (~9 ms of CPU a frame) took the
#: second core from the frame being tracked; niced, `default` on walking_xyz 22.9 -> 20.6 ms
#: median (5 alternating runs each, the same wall time: 7.1 -> 7.0 s for 300 frames).


#: Where the tracking thread runs alone (``tracking_core``, ``slam.pin_tracking``): one CPU
#: for the thread that tracks, the others for everything else. On 2 cores the scheduler
#: otherwise puts a background thread (local mapping, decoding, segmentation, niced +5 but
#: still given about a quarter of a shared core) beside tracking: `default` on walking_xyz
#: spent 3-4 ms a frame waiting for a core (run queue); pinned, 0.1 ms, but everything else
#: then shares one core (see ``SlamConfig.pin_tracking`` for why it is off by default).
#: The environment variable carries the background CPUs to worker processes.
BACKGROUND_CPUS_VARIABLE = "SEMSLAM_BACKGROUND_CPUS"


class tracking_core:  # noqa: N801  (used as a context manager, like a function)
    """While active, the thread that entered runs on one CPU of its own and the threads
    and processes that call ``move_off_tracking_core`` (every background thread of a run
    does, through ``lower_thread_priority``) run on the others. Needs Linux and two or
    more allowed CPUs; otherwise, or with ``enabled=False``, nothing changes.

    Several runs at once (two ``semslam run`` processes, a batch's workers) each take a
    different CPU: a CPU is claimed with a lock file (released when the process ends,
    however it ends), and a run that finds every CPU taken is not pinned. On exit the
    thread's CPUs are restored."""

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self.cpu: int | None = None
        self._allowed: set[int] = set()
        self._lock_fd: int | None = None

    def __enter__(self) -> "tracking_core":
        if not self.enabled or not hasattr(os, "sched_setaffinity"):
            return self
        try:
            self._allowed = set(os.sched_getaffinity(0))
        except OSError:
            return self
        if len(self._allowed) < 2 or os.environ.get(BACKGROUND_CPUS_VARIABLE):  # one pinned run per process
            return self
        for cpu in sorted(self._allowed):
            fd = _claim_cpu(cpu)
            if fd is None:
                continue
            try:
                os.sched_setaffinity(0, {cpu})
            except OSError:
                os.close(fd)
                return self
            self.cpu, self._lock_fd = cpu, fd
            os.environ[BACKGROUND_CPUS_VARIABLE] = ",".join(str(c) for c in sorted(self._allowed - {cpu}))
            break
        return self

    def __exit__(self, *exc: object) -> None:
        if self.cpu is None:
            return
        os.environ.pop(BACKGROUND_CPUS_VARIABLE, None)
        try:
            os.sched_setaffinity(0, self._allowed)
        except OSError:
            pass
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # releases the claim
        self.cpu = self._lock_fd = None


def _claim_cpu(cpu: int) -> int | None:
    """An open, exclusively locked lock file for ``cpu`` (close it to release), or None if
    another process holds it or locks cannot be had here."""
    import fcntl
    import tempfile

    path = os.path.join(tempfile.gettempdir(), f"semslam-tracking-cpu{cpu}.lock")
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def move_off_tracking_core() -> bool:
    """Run the calling thread (and what it starts later) on the CPUs ``tracking_core``
    left to background work, if a run's tracking thread is pinned; returns whether it
    moved."""
    cpus = os.environ.get(BACKGROUND_CPUS_VARIABLE)
    if not cpus or not hasattr(os, "sched_setaffinity"):
        return False
    try:
        os.sched_setaffinity(0, {int(c) for c in cpus.split(",")})
    except (OSError, ValueError):
        return False
    return True


def lower_thread_priority(increment: int | None = None) -> bool:
    """Run the calling thread off the tracking thread's CPU (``move_off_tracking_core``)
    and ``increment`` (default ``BACKGROUND_NICE``) below the process's main thread (Linux
    applies a niceness per thread). Relative to the process, not to the calling thread: a
    thread inherits the niceness of the thread that started it (a pool's worker starts in
    whichever thread first submits to it), so adding to its own would nice twice. Never
    raises nor raises priority: returns whether the thread is now that low (a platform
    without per-thread priorities just runs as is)."""
    import threading

    move_off_tracking_core()
    inc = BACKGROUND_NICE if increment is None else increment
    if inc <= 0 or not hasattr(os, "setpriority"):
        return False
    try:
        tid = threading.get_native_id()
        target = min(19, os.getpriority(os.PRIO_PROCESS, os.getpid()) + inc)
        if os.getpriority(os.PRIO_PROCESS, tid) < target:
            os.setpriority(os.PRIO_PROCESS, tid, target)
    except OSError:
        return False
    return True


# ---------------------------------------------------------------------------- stopping
#: Seconds between a worker process's checks that the process that started it still lives.
PARENT_POLL_S = 0.5

_stop_requested = False
#: The signal that asked for the stop (None: asked for in code, counted as SIGINT).
_stop_signal: int | None = None
_SIGINT = 2  # signal.SIGINT on every platform Python runs on


def request_stop(signum: int | None = None) -> None:
    """Ask the run in progress to stop after the current frame (what Ctrl-C / SIGTERM do);
    ``signum``: the signal that asked, for the exit code (``stop_exit_code``)."""
    global _stop_requested, _stop_signal
    _stop_requested = True
    _stop_signal = signum


def stop_requested() -> bool:
    """Whether a stop was asked for since the last ``clear_stop``."""
    return _stop_requested


def stop_exit_code() -> int:
    """128 + the number of the signal that asked for the stop, as shells report a command a
    signal ended: 130 for SIGINT (and a stop asked for in code), 143 for SIGTERM."""
    return 128 + (_stop_signal if _stop_signal is not None else _SIGINT)


def clear_stop() -> None:
    global _stop_requested, _stop_signal
    _stop_requested = False
    _stop_signal = None


class StopOnSignals:
    """While active (``with StopOnSignals():`` in the main thread), the first SIGINT or
    SIGTERM asks the run to stop after the current frame, so it shuts its threads and
    processes down and writes what it has; a second one exits at once (128 + its number:
    130 for SIGINT, 143 for SIGTERM), for a user who will not wait. The previous handlers
    come back on exit."""

    SIGNALS = ("SIGINT", "SIGTERM")

    def __init__(self) -> None:
        self._previous: dict[int, object] = {}

    def __enter__(self) -> "StopOnSignals":
        import signal
        import threading

        clear_stop()
        if threading.current_thread() is threading.main_thread():  # handlers live in the main thread only
            for name in self.SIGNALS:
                sig = getattr(signal, name)
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        import signal

        for sig, handler in self._previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]
        self._previous.clear()

    @staticmethod
    def _handle(signum: int, frame: object) -> None:
        # os.write, not sys.stderr: the handler runs between two bytecodes of the main thread,
        # which may be inside a write to stderr (the progress bar); a buffered write there
        # raises "reentrant call" out of the handler into whatever the main thread was doing.
        if stop_requested():
            _say("\nsemslam: stopped at once (second interrupt); outputs not written\n")
            os._exit(128 + int(signum))
        request_stop(int(signum))
        _say("\nsemslam: stopping after this frame and writing what exists (interrupt again to abort)\n")


def _say(text: str) -> None:
    try:
        os.write(2, text.encode())
    except OSError:
        pass


def exit_with_parent(poll_s: float = PARENT_POLL_S) -> None:
    """In a worker process: a daemon thread ends this process when the process that started
    it dies (SIGKILL, out of memory), which no pipe or queue tells a worker blocked waiting
    for its next job. Polls the parent's pid: an orphan is re-parented, its ``getppid`` changes."""
    import threading
    import time

    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
