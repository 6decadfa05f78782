"""The maps' own worker: background inpainting, then every map builder, off the tracking path.

DDL-SLAM builds its octree in a thread of its own. Here it is a process: OctoMap's ray
casting and Open3D's TSDF hold the GIL for tens of milliseconds per keyframe, which in a
thread would stall tracking on a 2-core machine (the BA worker exists for the same reason,
``backend/worker.py``). Keyframe snapshots are a few MB of arrays, cheap to send. One worker,
tasks in order: keyframes, pose corrections and the final write reach the builders in the
order the SLAM system issued them. A sequential (deterministic) run does the same work
in the calling thread.

The builders and the inpainter are created *inside* the worker from their registry names
and the maps config, so nothing but plain data crosses the process boundary.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import MapsConfig, SemanticsConfig
from semslam.core import registry
from semslam.core.protocols import KeyframeSnapshot, MapBuilder
from semslam.errors import WorkerFailed
from semslam.worker_processes import worker_pool

log = logging.getLogger(__name__)

#: Niceness of the maps' process: below tracking, the semantic thread and local mapping (a
#: map that lags a few keyframes costs nothing; a late frame does). Measured with
#: benchmarks/maps.py (default, 900 frames at camera rate, 2 cores): at +10 tracking's median
#: rose by 2.2 and 5.3 ms with the maps on; at +19 by 1.1 and -0.9 ms (run-to-run noise),
#: and the queue still shrinks over the run (first third max 13-14, last third 9, end 2-6).
MAP_NICE = 19


@dataclass
class _MapState:
    """What the worker holds: the builders, the inpainter, where inpainted frames go, counters."""

    builders: list[MapBuilder]
    inpainter: Any | None
    inpainted_dir: Path | None
    mask_dynamic: bool = True
    margin_px: int = 0
    segmenter: Any | None = None
    dynamic_classes: list[str] = field(default_factory=list)
    segmented_keyframes: int = 0
    keyframe_ms: list[float] = field(default_factory=list)
    inpaint_ms: list[float] = field(default_factory=list)
    dynamic_px: int = 0
    filled_px: int = 0
    synthesized_px: int = 0
    frames_written: int = 0


_STATE: _MapState | None = None


def _create_state(names: list[str], cfg: MapsConfig, inpainted_dir: Path | None, lower_priority: bool,
                  semantics: SemanticsConfig | None = None) -> bool:
    """Build the builders, the inpainter and the keyframe segmenter (in the worker when there is one)."""
    global _STATE
    if lower_priority:
        import os

        from semslam.runtime import limit_threads, move_off_tracking_core

        limit_threads()
        move_off_tracking_core()  # a worker process: off a pinned tracking thread's CPU
        try:
            os.nice(MAP_NICE)
        except OSError:
            pass
    inpainter = None
    if cfg.inpainting.enabled:
        from semslam.reconstruction.inpainting import BackgroundInpainter

        inpainter = BackgroundInpainter(cfg.inpainting)
    segmenter = None
    if semantics is not None:
        from semslam.semantics.base import create_segmenter

        segmenter = create_segmenter(semantics)
    _STATE = _MapState([registry.create("map_builder", n, cfg) for n in names], inpainter, inpainted_dir,
                       cfg.mask_dynamic, cfg.dynamic_margin_px, segmenter,
                       list(semantics.dynamic_classes) if semantics is not None else [])
    return True


def _state() -> _MapState:
    if _STATE is None:
        raise RuntimeError("map worker used before it was started")
    return _STATE


def _add_keyframe(snapshot: KeyframeSnapshot) -> None:
    st = _state()
    t0 = time.perf_counter()
    if st.segmenter is not None and snapshot.labels is None and st.mask_dynamic:
        snapshot = _segment(st, snapshot)
    if not st.mask_dynamic:
        snapshot = replace(snapshot, dynamic=None)
    elif st.margin_px > 0 and snapshot.dynamic is not None and snapshot.dynamic.any():
        k = 2 * st.margin_px + 1
        grown = cv2.dilate(snapshot.dynamic.view(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
        snapshot = replace(snapshot, dynamic=grown)
    if st.inpainter is not None:
        dynamic = snapshot.dynamic
        snapshot = st.inpainter.inpaint(snapshot)
        t1 = time.perf_counter()
        st.inpaint_ms.append((t1 - t0) * 1e3)
        if dynamic is not None:
            st.dynamic_px += int(dynamic.sum())
            st.filled_px += int(snapshot.filled.sum()) if snapshot.filled is not None else 0
            st.synthesized_px += int(snapshot.synthesized.sum()) if snapshot.synthesized is not None else 0
        if st.inpainted_dir is not None:
            _write_inpainted(st, snapshot)
    for builder in st.builders:
        builder.add_keyframe(snapshot)
    st.keyframe_ms.append((time.perf_counter() - t0) * 1e3)


def _segment(st: _MapState, snapshot: KeyframeSnapshot) -> KeyframeSnapshot:
    """A keyframe tracking did not wait to segment (``semantics.schedule: latest`` and
    ``stride``: its mask was warped from an earlier frame) is segmented here, off the
    tracking path; its classes join the mask tracking used (which holds the moving regions)."""
    from semslam.semantics.base import dynamic_mask, fit_labels

    labels = fit_labels(st.segmenter.segment(snapshot.rgb), snapshot.rgb.shape[:2])
    own = dynamic_mask(labels, st.dynamic_classes)
    st.segmented_keyframes += 1
    return replace(snapshot, labels=labels, dynamic=own if snapshot.dynamic is None else own | snapshot.dynamic)


def _add_frame(snapshot: KeyframeSnapshot) -> None:
    """A frame that is not a keyframe: inpainted from the history and written, not mapped."""
    st = _state()
    if st.inpainter is None or st.inpainted_dir is None:
        return
    _write_inpainted(st, st.inpainter.inpaint(snapshot, remember=False))


def _write_inpainted(st: _MapState, snapshot: KeyframeSnapshot) -> None:
    from semslam.reconstruction.inpainting import write_inpainted

    assert st.inpainted_dir is not None
    write_inpainted(st.inpainted_dir, f"{snapshot.timestamp:.6f}", snapshot)
    st.frames_written += 1


def _correct_poses(poses_wc: dict[int, NDArray[np.float64]]) -> None:
    st = _state()
    if st.inpainter is not None:
        st.inpainter.correct_poses(poses_wc)
    for builder in st.builders:
        builder.correct_poses(poses_wc)


def _finish(out_dir: Path) -> tuple[dict[str, Path], dict[str, float]]:
    st = _state()
    paths: dict[str, Path] = {}
    t0 = time.perf_counter()
    for builder in st.builders:
        paths.update(builder.finish(out_dir))
    stats: dict[str, float] = {
        "map_keyframes": len(st.keyframe_ms),
        "map_segmented_keyframes": st.segmented_keyframes,
        "map_keyframe_ms_median": float(np.median(st.keyframe_ms)) if st.keyframe_ms else 0.0,
        "map_finish_s": time.perf_counter() - t0,
    }
    if st.inpainter is not None:
        stats["inpaint_ms_median"] = float(np.median(st.inpaint_ms)) if st.inpaint_ms else 0.0
        stats["inpaint_dynamic_px"] = st.dynamic_px
        stats["inpaint_filled_share"] = st.filled_px / st.dynamic_px if st.dynamic_px else 0.0
        stats["inpaint_synthesized_share"] = st.synthesized_px / st.dynamic_px if st.dynamic_px else 0.0
        stats["inpainted_frames_written"] = st.frames_written
    return paths, stats


def _close() -> None:
    global _STATE
    if _STATE is not None:
        for builder in _STATE.builders:
            builder.close()
        if _STATE.segmenter is not None:
            _STATE.segmenter.close()
        _STATE = None


def queue_profile(lengths: list[int]) -> dict[str, float]:
    """Whether the maps keep pace: the queue's maximum over the first and the last third of
    the keyframes and at the end. A worker that keeps pace has a last third no worse than the
    first (which holds the start-up, while the worker process imports its libraries)."""
    if not lengths:
        return {}
    k = max(1, len(lengths) // 3)
    return {"map_queue_first_third_max": max(lengths[:k]), "map_queue_last_third_max": max(lengths[-k:]),
            "map_queue_end": lengths[-1]}


class MappingWorker:
    """``MapBuilder`` (and frame sink) in front of the maps' worker.

    ``add_keyframe`` / ``add_frame`` / ``correct_poses`` return at once (the work is queued);
    ``finish`` waits for the queue, writes every builder's files and returns their paths;
    ``stats`` says how far behind the maps ever were (``map_queue_max``) and what they cost.
    """

    def __init__(self, names: list[str], cfg: MapsConfig, threaded: bool,
                 inpainted_dir: Path | None = None, semantics: SemanticsConfig | None = None) -> None:
        for name in names:
            registry.resolve("map_builder", name)  # a typo fails here, before any frame
        self.names = list(names)
        self._pool: ProcessPoolExecutor | None = None
        self._pending: list[Future[Any]] = []
        self._error: BaseException | None = None
        self.queue_max = 0
        self.queue_lengths: list[int] = []  # tasks waiting after each keyframe was handed over
        self.wants_frames = inpainted_dir is not None and cfg.inpainting.enabled
        self.stats_: dict[str, float] = {}
        if threaded:
            self._pool = worker_pool()  # no orphan if the run is killed, no re-run of the user's script
            self._pending.append(self._pool.submit(_create_state, self.names, cfg, inpainted_dir, True, semantics))
        else:
            _create_state(self.names, cfg, inpainted_dir, False, semantics)

    # ------------------------------------------------------------------ MapBuilder contract
    def add_keyframe(self, snapshot: KeyframeSnapshot) -> None:
        self._call(_add_keyframe, snapshot)
        self.queue_lengths.append(len(self._pending))

    def add_frame(self, snapshot: KeyframeSnapshot) -> None:
        self._call(_add_frame, snapshot)

    def correct_poses(self, poses_wc: dict[int, NDArray[np.float64]]) -> None:
        self._call(_correct_poses, poses_wc)

    def finish(self, out_dir: Path) -> dict[str, Path]:
        self._drain()
        if self._pool is None:
            paths, self.stats_ = self._inline(_finish, out_dir)
        else:
            paths, self.stats_ = self._wait(self._pool.submit(_finish, out_dir))
        self.stats_.update(queue_profile(self.queue_lengths))
        self.stats_["map_queue_max"] = self.queue_max
        return paths

    def stats(self) -> dict[str, float]:
        return dict(self.stats_)

    def close(self) -> None:
        """Free the worker without writing anything: queued keyframes are dropped (a run
        stopping early does not wait for them), then the process ends."""
        for fut in self._pending:
            fut.cancel()
        if self._pool is not None:
            pool, self._pool = self._pool, None
            # Not terminated: a process killed while a snapshot is still being written to it
            # leaves the queue's feeder thread blocked on a full pipe, and the interpreter's
            # exit waits for that thread for ever (seen in CI). The keyframe in hand finishes,
            # queued ones are cancelled, and the process's exit frees the builders.
            pool.shutdown(wait=True, cancel_futures=True)
        else:
            _close()

    # ------------------------------------------------------------------ queue
    def _call(self, fn: Any, *args: Any) -> None:
        if self._pool is None:  # inline: a failure stops the maps, not tracking (as the worker's)
            if self._error is None:
                try:
                    fn(*args)
                except Exception as exc:  # noqa: BLE001 - raised as WorkerFailed at finish
                    self._error = exc
                    log.error("mapping failed: %s", exc)
            return
        self._pending = [f for f in self._pending if not f.done() or self._check(f)]
        if self._error is not None:  # the maps failed (or their process died): tracking goes on
            return
        try:
            self._pending.append(self._pool.submit(fn, *args))
        except Exception as exc:  # noqa: BLE001 - BrokenProcessPool: raised as WorkerFailed at finish
            self._error = exc
            log.error("mapping worker failed: %s", exc)
            return
        self.queue_max = max(self.queue_max, len(self._pending))

    def _check(self, fut: Future[Any]) -> bool:
        """Keep the first failure of a finished task (raised at ``finish``); never keep done tasks."""
        if self._error is None and fut.exception() is not None:
            self._error = fut.exception()
            log.error("mapping worker failed: %s", self._error)
        return False

    def _drain(self) -> None:
        for fut in self._pending:
            fut.exception()  # waits
            self._check(fut)
        self._pending = []
        if self._error is not None:
            raise WorkerFailed(f"mapping worker failed: {type(self._error).__name__}: {self._error}") \
                from self._error

    def _inline(self, fn: Any, *args: Any) -> Any:
        try:
            return fn(*args)
        except Exception as exc:
            raise WorkerFailed(f"mapping failed: {type(exc).__name__}: {exc}") from exc

    def _wait(self, fut: Future[Any]) -> Any:
        try:
            return fut.result()
        except Exception as exc:
            raise WorkerFailed(f"mapping worker failed: {type(exc).__name__}: {exc}") from exc
