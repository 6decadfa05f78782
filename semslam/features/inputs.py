"""The input check every extractor shares: what ``Extractor.extract`` accepts."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray


def check_extractor_inputs(gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None
                           ) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
    """A uint8 grey image (colour is converted) and a uint8 mask of the same size, or an error."""
    gray = np.asarray(gray)
    if gray.ndim == 3:
        gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY if gray.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if gray.dtype != np.uint8 or gray.ndim != 2:
        raise ValueError(f"expected a uint8 grey image, got {gray.dtype} {gray.shape}")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != gray.shape:
            raise ValueError(f"mask shape {mask.shape} differs from the image's {gray.shape}")
        mask = np.ascontiguousarray(mask) if mask.dtype == np.uint8 else (mask != 0).view(np.uint8)
    return gray, mask
