"""Per-stage timing of an extraction (for profiling and the benchmark)."""

from __future__ import annotations

import time

__all__ = ["StageClock"]


class StageClock:
    """Wall and thread-CPU time at the start and at the end of each stage: call
    ``lap()`` after each stage. Why both: wall time includes waiting for the CPU on a
    busy machine, the thread's CPU time barely does."""

    def __init__(self) -> None:
        self.wall = [time.perf_counter()]
        self.cpu = [time.thread_time()]

    def lap(self) -> None:
        self.wall.append(time.perf_counter())
        self.cpu.append(time.thread_time())

    def stage_ms(self, names: tuple[str, ...]) -> tuple[dict[str, float], dict[str, float]]:
        """(wall, CPU) milliseconds of the stages, by name, in order."""
        wall = {n: 1e3 * (b - a) for n, a, b in zip(names, self.wall, self.wall[1:])}
        cpu = {n: 1e3 * (b - a) for n, a, b in zip(names, self.cpu, self.cpu[1:])}
        return wall, cpu
