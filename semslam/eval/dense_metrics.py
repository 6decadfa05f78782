"""Per-pixel metrics of SDF-SLAM's Tables 8 and 9: MPA and MIoU (eqs. 16-17) of a label map,
RMS, REL and the delta < 1.25^k accuracies (eqs. 18-20) of a depth map. Pure numpy.

Counts accumulate over frames (a confusion matrix, sums of errors), so a sequence's score
weighs every pixel once, as the equations' sums over N pixels do.

* MPA (eq. 16): mean over classes of p_ii / sum_j p_ij (row i = pixels whose truth is i).
* MIoU (eq. 17): mean over classes of p_ii / (sum_j p_ij + sum_j p_ji - p_ii). Eq. 17 as
  printed adds p_ii to both sums without subtracting it once, which would cap IoU at 1/2;
  this is the standard IoU it names ("intersection over union").
* Both average over the classes that occur: MPA over classes present in the truth, MIoU over
  classes present in the truth or the prediction (eq. 16's 1/(K+1) assumes every class occurs).
* RMS (eq. 18) sqrt(mean (D - D*)^2); REL (eq. 19) mean |D - D*| / D with D the true depth
  (the usual definition; the paper's text swaps the symbols' names); delta_k (eq. 20): share
  of pixels with max(D / D*, D* / D) < 1.25^k. Only pixels with a true depth (> 0) count; a
  prediction <= 0 counts as wrong for the deltas.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

IGNORE_INDEX = 255
DELTA_BASE = 1.25


def confusion(truth: NDArray[np.integer], pred: NDArray[np.integer], n: int,
              ignore: int = IGNORE_INDEX) -> NDArray[np.int64]:
    """(n, n) pixel counts, row = true class, column = predicted class; ``ignore`` skipped."""
    t = np.asarray(truth).ravel().astype(np.int64)
    p = np.asarray(pred).ravel().astype(np.int64)
    keep = (t != ignore) & (t >= 0) & (t < n)
    p = np.clip(p[keep], 0, n - 1)
    return np.bincount(t[keep] * n + p, minlength=n * n).reshape(n, n)


def mean_pixel_accuracy(conf: NDArray[np.integer]) -> float:
    """Eq. 16 over the classes present in the truth (NaN if none)."""
    conf = np.asarray(conf, np.float64)
    rows = conf.sum(1)
    present = rows > 0
    return float(np.mean(np.diag(conf)[present] / rows[present])) if present.any() else float("nan")


def class_iou(conf: NDArray[np.integer]) -> NDArray[np.float64]:
    """Per-class IoU (eq. 17's term), NaN for classes in neither truth nor prediction."""
    conf = np.asarray(conf, np.float64)
    tp = np.diag(conf)
    union = conf.sum(0) + conf.sum(1) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, tp / union, np.nan)


def mean_iou(conf: NDArray[np.integer]) -> float:
    """Eq. 17: mean IoU over the classes that occur (NaN if none)."""
    iou = class_iou(conf)
    return float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan")


@dataclass
class DepthErrors:
    """Accumulates eqs. 18-20 over frames; :meth:`result` gives the pooled metrics."""

    n: int = 0
    sum_sq: float = 0.0
    sum_rel: float = 0.0
    within: list[int] = field(default_factory=lambda: [0, 0, 0])

    def add(self, pred: NDArray[np.floating], truth: NDArray[np.floating]) -> None:
        pred = np.asarray(pred, np.float64)
        truth = np.asarray(truth, np.float64)
        if pred.shape != truth.shape:
            raise ValueError(f"depth prediction {pred.shape} and truth {truth.shape} differ in shape")
        valid = truth > 0
        d, t = pred[valid], truth[valid]
        self.n += int(d.size)
        self.sum_sq += float(np.sum((d - t) ** 2))
        self.sum_rel += float(np.sum(np.abs(d - t) / t))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(d > 0, np.maximum(d / t, t / np.where(d > 0, d, 1.0)), np.inf)
        for k in range(3):
            self.within[k] += int(np.sum(ratio < DELTA_BASE ** (k + 1)))

    def merge(self, other: DepthErrors) -> None:
        """Add another accumulator's pixels (pooling sequences)."""
        self.n += other.n
        self.sum_sq += other.sum_sq
        self.sum_rel += other.sum_rel
        self.within = [a + b for a, b in zip(self.within, other.within)]

    def result(self) -> dict[str, float]:
        if self.n == 0:
            nan = float("nan")
            return {"rms": nan, "rel": nan, "delta1": nan, "delta2": nan, "delta3": nan, "pixels": 0}
        return {"rms": (self.sum_sq / self.n) ** 0.5, "rel": self.sum_rel / self.n,
                "delta1": self.within[0] / self.n, "delta2": self.within[1] / self.n,
                "delta3": self.within[2] / self.n, "pixels": self.n}


def depth_metrics(pred: NDArray[np.floating], truth: NDArray[np.floating]) -> dict[str, float]:
    """Eqs. 18-20 of one depth map against the truth."""
    acc = DepthErrors()
    acc.add(pred, truth)
    return acc.result()
