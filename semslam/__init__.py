"""semslam: semantic visual SLAM for scenes that are not static.

``from semslam import System`` gives the Python API (``semslam/api.py``): SLAM fed frame by
frame from user code. It is imported on first use, so ``import semslam`` stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from semslam.api import System

__version__ = "0.1.0"
__all__ = ["System", "__version__"]


def __getattr__(name: str) -> Any:
    if name == "System":
        from semslam.api import System

        return System
    raise AttributeError(f"module 'semslam' has no attribute {name!r}")
