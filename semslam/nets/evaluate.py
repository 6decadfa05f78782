"""Checking trained segmenters end to end: IoU on labelled folders, the real TUM frame, overlays.

Unlike the training loop's validation (network size, train indices), this runs the
segmenter backend exactly as SLAM does (full-size frame in, label ids out), so it also
tests the resizing and thresholding.

The real check uses ``fr3_walking_person.png`` (TUM fr3 walking, person on the left,
x < ~260, and part of a second person at the right edge). It has no labels; its
reference mask is the GrabCut cut-out the synthetic renderer makes of the same person
(``semslam.synth.people``), which is approximate at the boundary. Caveat: that renderer
pastes this very person into the synthetic sequences, so a network trained on them has
seen this person's appearance (not this background): the real-frame score is an
optimistic check of transfer, not an independent test.

    python -m semslam.nets.evaluate --weights semslam/data/stdc_person.pt \\
        --folder /tmp/val_seq --real ../shared/data/images_people/fr3_walking_person.png \\
        --out-dir /tmp/nets_preview
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.nets.datasets import read_label, tum_pairs
from semslam.nets.segmenters import DunetSegmenter, NetSegmenter, StdcSegmenter

PERSON = 15
LEFT_PERSON_MAX_X = 300  # the reference mask covers the left person only


def person_iou(pred: NDArray[np.uint8], truth: NDArray[np.bool_]) -> float:
    p = pred == PERSON
    union = np.logical_or(p, truth).sum()
    return float(np.logical_and(p, truth).sum() / union) if union else float("nan")


def evaluate_folder(seg: NetSegmenter, folder: Path, every: int = 1, limit: int = 0) -> dict[str, Any]:
    """Person IoU (accumulated over frames), mIoU over {background, person}, ms per frame."""
    inter = union = bg_inter = bg_union = 0
    times = []
    pairs = tum_pairs(folder)[::every]
    if limit:
        pairs = pairs[:limit]
    for rgb_path, lab_path in pairs:
        rgb = cv2.cvtColor(cv2.imread(str(rgb_path)), cv2.COLOR_BGR2RGB)
        truth = read_label(lab_path) == PERSON
        t0 = time.perf_counter()
        pred, _ = seg.segment(rgb)
        times.append(time.perf_counter() - t0)
        p = pred == PERSON
        inter += int(np.logical_and(p, truth).sum())
        union += int(np.logical_or(p, truth).sum())
        bg_inter += int(np.logical_and(~p, ~truth).sum())
        bg_union += int(np.logical_or(~p, ~truth).sum())
    iou_p = inter / union if union else float("nan")
    iou_b = bg_inter / bg_union if bg_union else float("nan")
    return {"folder": str(folder), "frames": len(pairs), "person_iou": iou_p, "background_iou": iou_b,
            "miou": (iou_p + iou_b) / 2, "ms_per_frame_p50": 1e3 * float(np.median(times))}


def reference_mask(image_path: Path) -> NDArray[np.bool_] | None:
    """GrabCut mask of the left person of fr3_walking_person.png (None if not that photo)."""
    from semslam.synth import people

    if Path(image_path).name != people.PHOTO:
        return None
    try:
        ub = people.cutout_photo(Path(image_path))  # the same cut-out the renderer uses
    except Exception:  # noqa: BLE001 - any failure means "no reference"
        return None
    # cutout_photo crops x 30..290, y 30..480, then to the mask's top row / column span.
    full = np.zeros((480, 640), bool)
    bgr = cv2.imread(str(image_path))
    sub = np.zeros((450, 260), np.uint8)
    # Rebuild the crop offsets: the RGBA sprite is sub[top:, left:right]; find them by matching.
    h, w = ub.rgba.shape[:2]
    region = cv2.cvtColor(bgr[30:480, 30:290], cv2.COLOR_BGR2RGB)
    res = cv2.matchTemplate(region, np.ascontiguousarray(ub.rgba[..., :3]), cv2.TM_SQDIFF)
    _, _, (left, top), _ = cv2.minMaxLoc(res)
    sub[top : top + h, left : left + w] = ub.rgba[..., 3]
    full[30:480, 30:290] = sub > 127
    return full


def overlay(rgb: NDArray[np.uint8], labels: NDArray[np.uint8], ref: NDArray[np.bool_] | None = None) -> NDArray[np.uint8]:
    """BGR image: person pixels tinted red, the reference outline in green."""
    out = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR).astype(np.float32)
    m = labels == PERSON
    out[m] = 0.5 * out[m] + 0.5 * np.array([0, 0, 255], np.float32)
    out = out.astype(np.uint8)
    if ref is not None:
        cnts, _ = cv2.findContours(ref.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(out, cnts, -1, (0, 255, 0), 1)
    return out


def real_frame_check(seg: NetSegmenter, image_path: Path, out_png: Path | None = None) -> dict[str, Any]:
    """Person IoU against the GrabCut reference (left part) and where the predicted person pixels are."""
    rgb = cv2.cvtColor(cv2.imread(str(image_path)), cv2.COLOR_BGR2RGB)
    pred, _ = seg.segment(rgb)
    ref = reference_mask(image_path)
    p = pred == PERSON
    res: dict[str, Any] = {
        "image": str(image_path),
        "person_pixels": int(p.sum()),
        "person_pixels_left_x_lt_260": int(p[:, :260].sum()),
        "person_pixels_right_x_ge_600": int(p[:, 600:].sum()),
        "person_pixels_middle": int(p[:, 260:600].sum()),
    }
    if ref is not None:
        left = slice(0, LEFT_PERSON_MAX_X)
        res["reference_pixels"] = int(ref.sum())
        res["person_iou_left_vs_grabcut"] = person_iou(pred[:, left], ref[:, left])
        res["recall_left"] = float(np.logical_and(p, ref).sum() / max(1, ref.sum()))
    if out_png is not None:
        out_png.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out_png), overlay(rgb, pred, ref))
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--weights", type=Path, required=True)
    ap.add_argument("--folder", type=Path, action="append", default=[], help="labelled TUM folder")
    ap.add_argument("--real", type=Path, action="append", default=[], help="real image (overlay + check)")
    ap.add_argument("--out-dir", type=Path, default=Path("/tmp/nets_preview"))
    ap.add_argument("--threshold", type=float, default=0.5)
    ap.add_argument("--input-width", type=int, default=0)
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    import torch

    torch.set_num_threads(a.threads)
    import semslam.nets.models as models

    _, meta = models.load_checkpoint(a.weights)
    cls = StdcSegmenter if meta["arch"] == "stdc1" else DunetSegmenter
    seg = cls(a.weights, a.threshold, a.input_width)
    a.out_dir.mkdir(parents=True, exist_ok=True)
    out: dict[str, Any] = {"weights": str(a.weights), "arch": meta["arch"], "width": meta["width"],
                           "input_width": seg.input_width, "threshold": seg.threshold, "folders": [], "real": []}
    for f in a.folder:
        out["folders"].append(evaluate_folder(seg, f, a.every))
        pairs = tum_pairs(f)
        rgb_path, _ = pairs[len(pairs) // 2]
        rgb = cv2.cvtColor(cv2.imread(str(rgb_path)), cv2.COLOR_BGR2RGB)
        lab, _ = seg.segment(rgb)
        cv2.imwrite(str(a.out_dir / f"{a.weights.stem}_{f.name}.png"), overlay(rgb, lab))
    for r in a.real:
        out["real"].append(real_frame_check(seg, r, a.out_dir / f"{a.weights.stem}_{r.stem}.png"))
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
