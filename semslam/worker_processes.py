"""How semslam starts its worker processes (the BA worker, the maps' worker): one place.

Threads run in the parent (tracking, local mapping, the semantic thread), so a plain
``fork`` of it could copy a lock some thread holds: workers are *spawned*, fresh
interpreters. Spawn normally re-imports the parent's ``__main__`` in the child (as
``__mp_main__``), so a user's script without ``if __name__ == "__main__":`` ran again in
every worker: it built a second ``System``, whose pool start then failed with ~300 lines of
multiprocessing errors (``default``) or broke the loop-closing worker (``orb``).
``forkserver`` does not help: its server preloads ``__main__`` and each child gets the same
preparation data as under spawn.

Nothing a worker runs comes from the user's module (its jobs are semslam functions, its
builders come from the registry by name), so the child is told nothing about ``__main__``:
while a worker starts, ``__main__.__file__`` and ``__spec__`` are hidden, which is what
``multiprocessing.spawn.get_preparation_data`` reads to decide whether to re-import it (as
it leaves alone a ``python -c`` or an interactive session's ``__main__``). The window is
the ``start()`` call (a few ms), under a lock, so two workers starting at once from two
threads restore the attributes correctly.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from multiprocessing.context import SpawnContext, SpawnProcess

from semslam.runtime import exit_with_parent

#: What spawn's preparation data reads from ``__main__`` to re-import it in the child.
_MAIN_ATTRIBUTES = ("__file__", "__spec__")
_MISSING = object()
_lock = threading.Lock()


@contextmanager
def main_module_hidden() -> Iterator[None]:
    """While active, a process spawned by this process does not re-import ``__main__``."""
    main = sys.modules.get("__main__")
    if main is None:
        yield
        return
    with _lock:
        saved = {name: main.__dict__.get(name, _MISSING) for name in _MAIN_ATTRIBUTES}
        main.__dict__.pop("__file__", None)
        main.__dict__["__spec__"] = None  # get_preparation_data reads __spec__.name first
        try:
            yield
        finally:
            for name, value in saved.items():
                if value is _MISSING:
                    main.__dict__.pop(name, None)
                else:
                    main.__dict__[name] = value


class _WorkerProcess(SpawnProcess):
    """A spawned process whose child does not run the parent's main module."""

    def start(self) -> None:
        with main_module_hidden():
            super().start()


class _WorkerContext(SpawnContext):
    """Spawn, with ``_WorkerProcess``: what ``ProcessPoolExecutor`` builds its workers from."""

    Process = _WorkerProcess


WORKER_CONTEXT = _WorkerContext()


def worker_pool() -> ProcessPoolExecutor:
    """A pool of one worker process that ends with its parent (``exit_with_parent``: a
    worker blocked waiting for its next job would otherwise outlive a SIGKILLed run) and
    does not re-run the user's script. The process starts at the first ``submit``."""
    return ProcessPoolExecutor(max_workers=1, mp_context=WORKER_CONTEXT, initializer=exit_with_parent)
