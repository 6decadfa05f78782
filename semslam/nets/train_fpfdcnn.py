"""Training FPFDCNN on the FP dataset (``nets/fp_dataset.py``) on CPU.

Losses (the paper names the tasks, not the losses; these are SuperPoint's choices adapted
to Table 12's per-pixel sigmoid):

* detector: binary cross-entropy of the per-pixel logits against the Harris corners of the
  *clear* frame, each a Gaussian bump (sigma ``heat_sigma`` = 1 px, peak 1: with one-pixel
  targets a first run of 260 steps learnt a nearly flat map), positive term weighted by
  ``pos_weight`` (corners are ~0.5 % of the pixels). The network often sees the frame
  blurred, so it learns to find the clear frame's corners in a blurred image.
  With ``target="harris"`` the label is instead the clear frame's dense Harris response,
  divided by its 99.5th percentile and clipped to [0, 1] (every pixel gets a graded
  target: a local function the network can learn in few steps, whose maxima are Harris's).
* descriptor: SuperPoint's hinge loss on the sampled correspondences of a pair (frame i's
  corners and their eq. 5-7 transfers into frame j): for M correspondences the M x M
  cosine similarities s; positives max(0, 1 - s_kk), negatives max(0, s_kl - 0.2) for
  pairs whose frame-j points are more than 8 px apart; mean of each, added.

* repeatability (``repeat_weight`` > 0; after R2D2's, Revaud et al. 2019, and KP2D's
  self-supervised keypoint consistency): frame j's keypoint logits are warped into frame i
  densely with the ground-truth depth and poses (the eq. 5-7 transfer of every pixel of the
  crop, ``transfer_corners``' rules: valid depth, no depth edge, inside, not occluded). In
  patches of ``repeat_patch`` px (stride half that) that are mostly valid and hold a
  detector label (a target above 0.3), each view's logits are a softmax over the patch's
  pixels, scored by cross-entropy against the other view's most probable pixel there
  (detached), both ways. R2D2's own term (1 - cosine similarity of the two maps) is
  satisfied by flat maps: on this detector it read 0.02 from the first step and training
  with it flattened the maps (Table 6 fell). The cross-entropy is lowest for one sharp
  maximum on the same pixel in both views. Harris labels alone leave the maxima where the
  net puts them in each view: 52 % of the shipped detector's points were re-detected
  within 3 px on the benchmark renders, Harris's own 84 %.

* "cells" detector (``target="cells"``): SuperPoint's loss on Table 12's logits: each
  ``CELL_PX`` x ``CELL_PX`` cell's 64 logits and a "no corner" logit fixed at 0 (sigmoid
  0.5) form a softmax, labelled with the cell's strongest Harris corner or "no corner".
  The maxima it trains are one pixel wide, where the dense Harris target gives blobs.

Loss = detector + ``desc_weight`` x descriptor + ``repeat_weight`` x repeatability. Adam, learning rate decayed linearly over
the time budget (``minutes``) or the steps. Pairs: frames i and i + gap (gap drawn from
``gaps``) of the training folders, each image blurred with probability ``blur_p`` (the
FP dataset's kernels), the same random crop in both (the camera moves little between
them), brightness / contrast jitter. The checkpoint is written at the end with the
validation metrics (losses, and the share of correct range-matcher matches within +-5 px
on the held-out folder's clear and blurred pairs).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from semslam.errors import ConfigError
from semslam.eval.feature_eval import correct_matches
from semslam.geometry.camera import PinholeCamera
from semslam.nets.fp_dataset import FPSequence, blur, harris_corners, harris_response, transfer_corners
from semslam.nets.fpfdcnn import FPFDCNN, count_parameters, load_fpfdcnn, sample_descriptors, save_fpfdcnn

POS_MARGIN, NEG_MARGIN, NEG_MIN_PX = 1.0, 0.2, 8.0
TARGETS = ("corners", "harris", "cells")
CELL_PX = 8  # cell side of the "cells" detector loss (SuperPoint's)


@dataclass
class FPTrainConfig:
    out: Path
    data: list[Path]
    val: list[Path] = field(default_factory=list)
    width: float = 0.5
    steps: int = 2000
    minutes: float = 0.0  # time budget (0 = run ``steps``)
    batch: int = 4  # pairs per step
    crop: tuple[int, int] = (320, 240)  # (w, h), multiples of 16
    gaps: tuple[int, ...] = (1, 2, 3, 4)
    blur_p: float = 0.5
    lr: float = 1e-3
    pos_weight: float = 20.0
    desc_weight: float = 1.0
    n_corr: int = 128  # correspondences per pair in the descriptor loss
    max_corners: int = 1000  # Harris corners per frame (labels and correspondences)
    min_distance: int = 4  # px between them
    heat_sigma: float = 1.0
    target: str = "corners"  # "corners" (Gaussian bumps), "harris" (dense response) or "cells" (cell softmax)
    repeat_weight: float = 0.0  # weight of the repeatability loss (0 = off: no depth kept in memory)
    repeat_patch: int = 8  # its patch side (px)
    seed: int = 0
    threads: int = 1
    init: Path | None = None  # continue from these weights (their width) instead of random ones
    command: str = ""


@dataclass
class _Pair:
    i: int
    j: int
    xy1: np.ndarray
    xy2: np.ndarray
    camera: PinholeCamera  # the folder's


class FPTrainData:
    """Grey frames, their Harris corners and the correspondences of every (i, i + gap)
    pair of some TUM-layout folders, in memory."""

    def __init__(self, folders: list[Path], gaps: tuple[int, ...], max_corners: int = 1000,
                 min_distance: int = 4, heat_sigma: float = 1.0, target: str = "corners",
                 dense: bool = False) -> None:
        if target not in TARGETS:
            raise ConfigError(f"train fpfdcnn: --target must be one of {', '.join(TARGETS)}, got {target!r}")
        self.heat_sigma = heat_sigma
        self.target = target
        self.dense = dense  # keep depth and poses for the dense warp of each batch
        self.depth: list[np.ndarray] = []
        self.pose: list[np.ndarray] = []
        self.harris_scale: list[float] = []
        self.gray: list[np.ndarray] = []
        self.corners: list[np.ndarray] = []
        self.pairs: list[_Pair] = []
        for folder in folders:
            seq = FPSequence(folder, max_corners)
            base = len(self.gray)
            frames = [seq.load(k) for k in range(len(seq))]
            for k, (g, d) in enumerate(frames):
                self.gray.append(g)
                if dense:
                    self.depth.append(d)
                    self.pose.append(seq.poses[k])
                self.corners.append(harris_corners(g, max_corners, min_distance=min_distance))
                self.harris_scale.append(float(np.quantile(harris_response(g), 0.995)) or 1.0)
            for gap in gaps:
                for i, j in seq.pair_indices(gap):
                    xy1 = self.corners[base + i]
                    xy2, ok = transfer_corners(xy1, frames[i][1], frames[j][1], seq.camera, seq.poses[i], seq.poses[j])
                    if ok.sum() >= 8:
                        self.pairs.append(_Pair(base + i, base + j, xy1[ok], xy2[ok].astype(np.float32), seq.camera))
        if not self.pairs:
            raise ConfigError(f"train fpfdcnn: no frame pairs with correspondences in {', '.join(map(str, folders))}")

    def batch(self, rng: np.random.Generator, n: int, crop: tuple[int, int], blur_p: float, n_corr: int
              ) -> dict[str, torch.Tensor]:
        """``n`` random pairs: images (2n, 1, h, w), heat targets (2n, 1, h, w), matched
        points (n, n_corr, 2) twice and their mask (n, n_corr); with ``dense``, also where
        each pixel of the first crop lies in the second (``grid`` (n, h, w, 2), grid_sample's
        coordinates) and whether it is seen there (``valid`` (n, 1, h, w))."""
        cw, ch = crop
        imgs, heats, cells, grids, valids = [], [], [], [], []
        xa = np.zeros((n, n_corr, 2), np.float32)
        xb = np.zeros((n, n_corr, 2), np.float32)
        mask = np.zeros((n, n_corr), bool)
        for b in range(n):
            p = self.pairs[int(rng.integers(len(self.pairs)))]
            h, w = self.gray[p.i].shape
            x0, y0 = int(rng.integers(0, w - cw + 1)), int(rng.integers(0, h - ch + 1))
            for k in (p.i, p.j):
                g = self.gray[k]
                g = blur(g, rng) if rng.random() < blur_p else g
                g = g[y0:y0 + ch, x0:x0 + cw].astype(np.float32) * rng.uniform(0.7, 1.3) + rng.uniform(-25, 25)
                imgs.append(np.clip(g, 0, 255) / 255.0)
                if self.target == "harris":
                    heats.append(np.clip(harris_response(self.gray[k])[y0:y0 + ch, x0:x0 + cw] / self.harris_scale[k], 0, 1))
                    continue
                heat = np.zeros((ch, cw), np.float32)
                c = np.rint(self.corners[k]).astype(int) - [x0, y0]
                c = c[(c[:, 0] >= 0) & (c[:, 0] < cw) & (c[:, 1] >= 0) & (c[:, 1] < ch)]
                heat[c[:, 1], c[:, 0]] = 1.0
                if self.target == "cells":
                    cells.append(_cell_labels(c, cw, ch))
                if self.heat_sigma > 0:  # Gaussian bumps of peak 1
                    heat = np.minimum(cv2.GaussianBlur(heat, (0, 0), self.heat_sigma)
                                      * (2 * np.pi * self.heat_sigma ** 2), 1.0)
                heats.append(heat)
            a, bb = p.xy1 - [x0, y0], p.xy2 - [x0, y0]
            inside = ((a >= 0) & (a <= [cw - 1, ch - 1])).all(1) & ((bb >= 0) & (bb <= [cw - 1, ch - 1])).all(1)
            idx = np.flatnonzero(inside)
            idx = rng.permutation(idx)[:n_corr]
            xa[b, :len(idx)], xb[b, :len(idx)], mask[b, :len(idx)] = a[idx], bb[idx], True
            if self.dense:
                grid, valid = self._dense_warp(p, x0, y0, cw, ch)
                grids.append(grid)
                valids.append(valid)
        out = {"img": torch.from_numpy(np.stack(imgs)[:, None].astype(np.float32)),
               "heat": torch.from_numpy(np.stack(heats)[:, None].astype(np.float32)),
               "xa": torch.from_numpy(xa), "xb": torch.from_numpy(xb), "mask": torch.from_numpy(mask)}
        if cells:
            out["cells"] = torch.from_numpy(np.stack(cells))
        if self.dense:
            out["grid"] = torch.from_numpy(np.stack(grids))
            out["valid"] = torch.from_numpy(np.stack(valids)[:, None])
        return out

    def _dense_warp(self, p: _Pair, x0: int, y0: int, cw: int, ch: int) -> tuple[np.ndarray, np.ndarray]:
        """Every pixel of frame ``p.i``'s crop moved into frame ``p.j``'s crop (same window):
        grid_sample coordinates (h, w, 2) (align_corners=False) and validity (h, w) float."""
        ys, xs = np.mgrid[y0:y0 + ch, x0:x0 + cw]
        xy1 = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
        xy2, ok = transfer_corners(xy1, self.depth[p.i], self.depth[p.j], p.camera,
                                   self.pose[p.i], self.pose[p.j])
        u, v = xy2[:, 0] - x0, xy2[:, 1] - y0
        ok &= (u >= 0) & (u <= cw - 1) & (v >= 0) & (v <= ch - 1)
        grid = np.stack([(u + 0.5) / cw * 2 - 1, (v + 0.5) / ch * 2 - 1], axis=1)
        grid = np.where(ok[:, None], grid, -2.0)  # outside: grid_sample reads zeros
        return grid.reshape(ch, cw, 2).astype(np.float32), ok.reshape(ch, cw).astype(np.float32)


def _cell_labels(corners: np.ndarray, cw: int, ch: int) -> np.ndarray:
    """SuperPoint's detector labels: for each ``CELL_PX`` cell of the crop, the position
    (row-major, 0..CELL_PX^2 - 1) of its strongest corner (``corners`` are strongest first,
    crop pixels), or CELL_PX^2 (no corner: the "dustbin") - (ch / CELL_PX, cw / CELL_PX) int64."""
    c = CELL_PX
    labels = np.full((ch // c, cw // c), c * c, np.int64)
    rev = corners[::-1]  # weakest first: numpy keeps the last of repeated indices, the strongest
    labels[rev[:, 1] // c, rev[:, 0] // c] = (rev[:, 1] % c) * c + rev[:, 0] % c
    return labels


class Losses(NamedTuple):
    """One batch's loss terms (module doc); ``repeat`` is 0 without a dense batch."""

    det: torch.Tensor
    desc: torch.Tensor
    repeat: torch.Tensor


def losses(model: FPFDCNN, batch: dict[str, torch.Tensor], pos_weight: float, repeat_patch: int = 8) -> Losses:
    """Detector (BCE, or the cell softmax with a "cells" batch), descriptor hinge and (with a
    dense batch) repeatability (module doc)."""
    logit, coarse = model.logits(batch["img"])
    if "cells" in batch:  # SuperPoint's cell softmax on the sigmoid head's logits, dustbin logit 0
        per_cell = F.pixel_unshuffle(logit, CELL_PX)
        dustbin = torch.zeros_like(per_cell[:, :1])
        det = F.cross_entropy(torch.cat([per_cell, dustbin], dim=1), batch["cells"])
    else:
        det = F.binary_cross_entropy_with_logits(logit, batch["heat"], pos_weight=torch.tensor(pos_weight))
    repeat = (repeatability(logit, batch["heat"], batch["grid"], batch["valid"], repeat_patch)
              if "grid" in batch else logit.sum() * 0)
    da = sample_descriptors(coarse[0::2], batch["xa"])
    db = sample_descriptors(coarse[1::2], batch["xb"])
    sim = da @ db.transpose(1, 2)  # (n, M, M)
    m = batch["mask"]
    valid = m[:, :, None] & m[:, None, :]
    eye = torch.eye(sim.shape[1], dtype=torch.bool)[None]
    far = torch.cdist(batch["xb"], batch["xb"]) > NEG_MIN_PX
    pos = valid & eye
    neg = valid & ~eye & far
    pos_l = torch.clamp(POS_MARGIN - sim, min=0)[pos].mean() if pos.any() else sim.sum() * 0
    neg_l = torch.clamp(sim - NEG_MARGIN, min=0)[neg].mean() if neg.any() else sim.sum() * 0
    return Losses(det, pos_l + neg_l, repeat)


def repeatability(logit: torch.Tensor, heat: torch.Tensor, grid: torch.Tensor, valid: torch.Tensor,
                  patch: int) -> torch.Tensor:
    """Cross-entropy, over labelled and mostly valid patches, of each view's keypoint logits
    (softmax over the patch's pixels) against the other view's most probable pixel there
    (detached): the first images' logits ``logit[0::2]`` and the second images' warped onto
    them. Both views must put their maximum on the same pixel, and sharply."""
    warped = F.grid_sample(logit[1::2], grid, mode="bilinear", padding_mode="border", align_corners=False)
    k, stride = patch, max(1, patch // 2)
    floor = torch.tensor(-1e4, dtype=logit.dtype)
    a, b = (F.unfold(torch.where(valid > 0, m, floor), k, stride=stride) for m in (logit[0::2], warped))
    use = ((F.avg_pool2d(valid, k, stride) > 0.75) & (F.max_pool2d(heat[0::2], k, stride) > 0.3)).flatten(1)
    if not bool(use.any()):
        return logit.sum() * 0
    ce = F.cross_entropy(a, b.argmax(1).detach(), reduction="none") + F.cross_entropy(b, a.argmax(1).detach(),
                                                                                     reduction="none")
    return ce[use].mean() / 2


#: (xy_q, desc_q, xy_t, desc_t) -> (query indices, train indices, distances): the range
#: matcher, passed in by the caller (features sit above nets).
MatchFn = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


def train(cfg: FPTrainConfig, say: Callable[[str], None] = lambda _: None, match: MatchFn | None = None
          ) -> dict[str, Any]:
    """Train, write ``cfg.out`` (float16) and return its metadata; with ``cfg.val`` and
    ``match``, validation includes the correct-match share."""
    if cfg.crop[0] % 16 or cfg.crop[1] % 16:
        raise ConfigError(f"train fpfdcnn: --crop sides must be multiples of 16, got {cfg.crop[0]}x{cfg.crop[1]}")
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    t0 = time.perf_counter()
    data = FPTrainData(cfg.data, cfg.gaps, cfg.max_corners, cfg.min_distance, cfg.heat_sigma, cfg.target,
                       dense=cfg.repeat_weight > 0)
    say(f"{len(data.gray)} frames, {len(data.pairs)} pairs in {time.perf_counter() - t0:.0f} s")
    model, init_meta = _initial_model(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    history: list[dict[str, float]] = []
    t_start = time.perf_counter()
    step, run_det, run_desc, run_rep = 0, 0.0, 0.0, 0.0
    while True:
        elapsed = time.perf_counter() - t_start
        frac = elapsed / (cfg.minutes * 60) if cfg.minutes > 0 else step / cfg.steps
        if frac >= 1.0:
            break
        for group in opt.param_groups:
            group["lr"] = cfg.lr * max(0.05, 1.0 - frac)
        batch = data.batch(rng, cfg.batch, cfg.crop, cfg.blur_p, cfg.n_corr)
        det, desc, rep = losses(model, batch, cfg.pos_weight, cfg.repeat_patch)
        loss = det + cfg.desc_weight * desc + cfg.repeat_weight * rep
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        run_det += float(det.detach())
        run_desc += float(desc.detach())
        run_rep += float(rep.detach())
        if step % 50 == 0:
            history.append({"step": step, "seconds": round(elapsed, 1), "det": round(run_det / 50, 5),
                            "desc": round(run_desc / 50, 5), "repeat": round(run_rep / 50, 5)})
            say(f"step {step} ({elapsed:.0f} s): detector {run_det / 50:.4f} descriptor {run_desc / 50:.4f}"
                f" repeatability {run_rep / 50:.4f}")
            run_det = run_desc = run_rep = 0.0
    model.eval()
    meta: dict[str, Any] = {
        "command": cfg.command, "data": [str(p) for p in cfg.data], "val_data": [str(p) for p in cfg.val],
        "steps": step, "batch_pairs": cfg.batch, "crop": list(cfg.crop), "gaps": list(cfg.gaps),
        "blur_p": cfg.blur_p, "lr": cfg.lr, "pos_weight": cfg.pos_weight, "desc_weight": cfg.desc_weight,
        "max_corners": cfg.max_corners, "min_distance": cfg.min_distance, "heat_sigma": cfg.heat_sigma,
        "target": cfg.target, "repeat_weight": cfg.repeat_weight, "repeat_patch": cfg.repeat_patch,
        "seed": cfg.seed, "train_seconds": round(time.perf_counter() - t_start, 1), "history": history,
        "losses": _loss_names(cfg),
        "full_width_parameters": count_parameters(FPFDCNN(1.0)),
    }
    if init_meta is not None:  # how the starting weights were made, so the chain is reproducible
        meta["init"] = {"path": str(cfg.init), "command": init_meta.get("command", ""),
                        "steps": init_meta.get("steps"), "train_seconds": init_meta.get("train_seconds"),
                        "init": init_meta.get("init")}
    if cfg.val:
        meta["val"] = validate(model, cfg, match)
        say(f"validation: {meta['val']}")
    save_fpfdcnn(cfg.out, model, meta)
    return meta


def _loss_names(cfg: FPTrainConfig) -> str:
    """The loss terms of a run, for its checkpoint's metadata."""
    det = ("SuperPoint cell softmax on Harris corners" if cfg.target == "cells"
           else f"weighted BCE on Harris {'response' if cfg.target == 'harris' else 'corners'}")
    names = f"detector: {det}; descriptor: SuperPoint hinge (1 / 0.2)"
    if cfg.repeat_weight > 0:
        names += f"; repeatability x {cfg.repeat_weight}: cross-entropy to the other view's patch maximum"
    return names


def _initial_model(cfg: FPTrainConfig) -> tuple[FPFDCNN, dict[str, Any] | None]:
    """Random weights of ``cfg.width``, or ``cfg.init``'s weights (float16 checkpoints come
    back as float32) with their metadata; a width other than the checkpoint's is refused
    rather than silently changed."""
    if cfg.init is None:
        return FPFDCNN(cfg.width), None
    model, meta = load_fpfdcnn(cfg.init)
    if abs(model.width - cfg.width) > 1e-9:
        raise ConfigError(f"train fpfdcnn: --init {cfg.init} has width {model.width}, --width is {cfg.width}")
    return model.train(), meta


@torch.no_grad()
def validate(model: FPFDCNN, cfg: FPTrainConfig, match: MatchFn | None, n_batches: int = 10) -> dict[str, Any]:
    """Losses on held-out pairs (fixed seed) and Table 6's correct-match share of FPFDCNN
    (500 points) + range matcher on the held-out folders' clear and blurred pairs (gap 3)."""
    data = FPTrainData(cfg.val, (3,), cfg.max_corners, cfg.min_distance, cfg.heat_sigma, cfg.target,
                       dense=cfg.repeat_weight > 0)
    vrng = np.random.default_rng(12345)
    det = desc = rep = 0.0
    for _ in range(n_batches):
        d, s, r = losses(model, data.batch(vrng, cfg.batch, cfg.crop, cfg.blur_p, cfg.n_corr), cfg.pos_weight,
                         cfg.repeat_patch)
        det, desc, rep = det + float(d) / n_batches, desc + float(s) / n_batches, rep + float(r) / n_batches
    out: dict[str, Any] = {"det_loss": round(det, 5), "desc_loss": round(desc, 5)}
    if cfg.repeat_weight > 0:
        out["repeat_loss"] = round(rep, 5)
    for blurred in (False, True) if match is not None else ():
        good = total = 0
        for folder in cfg.val:
            seq = FPSequence(folder)
            for i, j in seq.pair_indices(3, every=4):
                p = seq.pair(i, j, blurred=blurred, seed=cfg.seed)
                a, b = model.extract(p.gray1), model.extract(p.gray2)
                qi, ti, _ = match(a[:, :2], a[:, 2:], b[:, :2], b[:, 2:])
                judged, correct = correct_matches(a[qi, :2], b[ti, :2], p.depth1, p.camera, p.T_wc1, p.T_wc2)
                good, total = good + int(correct.sum()), total + int(judged.sum())
        out["blurred" if blurred else "clear"] = {"correct": good, "judged": total,
                                                  "rate": round(good / max(total, 1), 4)}
    return out
