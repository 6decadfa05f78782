"""Training STDC-Seg / DUNet on CPU: data loading, loop, validation mIoU, checkpointing.

Recipe (scaled down from STDC-Seg's Cityscapes recipe so it runs in minutes on 2 CPU
cores): AdamW (instead of SGD 0.01 for 60k iterations: far fewer steps are affordable
here and Adam gets there faster), linear warm-up then poly decay (power 0.9) as in
STDC/BiSeNet, weight decay on all weights. STDC is trained with its full loss (OHEM CE on
the main + 2 auxiliary outputs, detail BCE + dice); DUNet with plain cross-entropy (its
paper's loss for the 2-class vessel case) and its offset convs at 0.1x the learning rate
(usual DCN practice, also done by the DUNet code's deform_conv_v2). The checkpoint is
rewritten after every epoch, so an interrupted run still leaves usable weights.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader

from semslam.errors import ConfigError
from semslam.nets.datasets import (
    IGNORE_INDEX,
    MEAN,
    STD,
    Augment,
    ClassSet,
    SegDataset,
    describe_sources,
    load_samples,
    tum_pairs,
    voc_pairs,
)
from semslam.nets.models import build_model, input_multiple, save_checkpoint


@dataclass
class TrainConfig:
    arch: str  # "stdc1" or "dunet"
    out: Path
    data: list[Path] = field(default_factory=list)  # TUM folders with semantic/ (training)
    voc: list[Path] = field(default_factory=list)  # VOC folders (train split)
    val: list[Path] = field(default_factory=list)  # TUM folders for validation
    classes: ClassSet = field(default_factory=ClassSet)
    epochs: int = 10
    batch: int = 8
    size: tuple[int, int] = (320, 240)  # (w, h) images are resized to fit; validation size
    crop: tuple[int, int] | None = None  # training crop (w, h); default = size
    scale: tuple[float, float] = (0.5, 1.5)
    width: float = 0.5
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup: float = 0.05  # fraction of iterations
    every: int = 1  # take every n-th frame of TUM folders
    seed: int = 0
    threads: int = 0  # 0 = all cores
    minutes: float = 0.0  # stop (and save) after this long; 0 = no limit
    half: bool = True
    options: dict[str, Any] = field(default_factory=dict)  # architecture options (DUNet: modulation)
    init: Path | None = None  # start from these weights (same architecture), e.g. to train longer
    command: str = ""

    def validate(self) -> TrainConfig:
        if self.arch not in ("stdc1", "dunet"):
            raise ConfigError(f"train: unknown architecture {self.arch!r}")
        if not (self.data or self.voc):
            raise ConfigError("train: give at least one --data or --voc folder")
        m = input_multiple(self.arch)
        for name, s in (("size", self.size), ("crop", self.crop or self.size)):
            if s[0] % m or s[1] % m:
                raise ConfigError(f"train: --{name} {s[0]}x{s[1]} must be multiples of {m} for {self.arch}")
        if self.epochs < 1 or self.batch < 1:
            raise ConfigError("train: epochs and batch must be >= 1")
        if not 0.05 <= self.width <= 2.0:
            raise ConfigError(f"train: width {self.width} out of range (0.05..2)")
        return self


def confusion_matrix(pred: torch.Tensor, target: torch.Tensor, n: int) -> torch.Tensor:
    """(n, n) counts, rows = truth, columns = prediction; ignore pixels skipped."""
    keep = target != IGNORE_INDEX
    idx = target[keep] * n + pred[keep]
    return torch.bincount(idx, minlength=n * n).view(n, n)


def iou_from_confusion(conf: np.ndarray) -> np.ndarray:
    """Per-class IoU (NaN for classes absent from both truth and prediction)."""
    conf = conf.astype(np.float64)
    tp = np.diag(conf)
    denom = conf.sum(0) + conf.sum(1) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(denom > 0, tp / denom, np.nan)


@torch.inference_mode()
def evaluate(model: nn.Module, ds: SegDataset, n_classes: int, batch: int = 4) -> dict[str, Any]:
    """mIoU and per-class IoU of ``model`` on ``ds`` (at the dataset's fixed size)."""
    was_training = model.training
    model.eval()
    conf = torch.zeros(n_classes, n_classes, dtype=torch.int64)
    for x, y in DataLoader(ds, batch_size=batch, shuffle=False):
        pred = model(x).argmax(1)
        conf += confusion_matrix(pred, y, n_classes)
    model.train(was_training)
    iou = iou_from_confusion(conf.numpy())
    return {"miou": float(np.nanmean(iou)), "iou": [None if math.isnan(v) else float(v) for v in iou],
            "pixel_acc": float(conf.diag().sum() / max(1, conf.sum()))}


def _loss_fn(arch: str) -> Callable[[dict[str, torch.Tensor], torch.Tensor], tuple[torch.Tensor, dict[str, float]]]:
    if arch == "stdc1":
        from semslam.nets.stdc import stdc_loss

        return stdc_loss

    def ce(outputs: dict[str, torch.Tensor], labels: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        loss = F.cross_entropy(outputs["out"], labels, ignore_index=IGNORE_INDEX)
        return loss, {"ce": float(loss.detach())}

    return ce


def _param_groups(model: nn.Module, lr: float, wd: float) -> list[dict[str, Any]]:
    """Weight decay on conv weights only; DCN offset convs at 0.1x lr."""
    offsets = {id(p) for p in getattr(model, "offset_parameters", lambda: [])()}
    groups: dict[tuple[bool, bool], list[nn.Parameter]] = {}
    for p in model.parameters():
        key = (id(p) in offsets, p.ndim > 1)
        groups.setdefault(key, []).append(p)
    return [
        {"params": ps, "lr": lr * (0.1 if off else 1.0), "base_lr": lr * (0.1 if off else 1.0),
         "weight_decay": wd if decay else 0.0}
        for (off, decay), ps in groups.items()
    ]


def build_datasets(cfg: TrainConfig, say: Callable[[str], None]) -> tuple[SegDataset, SegDataset | None]:
    """Training (augmented) and validation (fixed size) datasets."""
    t0 = time.perf_counter()
    train_pairs = [p for d in cfg.data for p in tum_pairs(d)[:: cfg.every]]
    train_pairs += [p for d in cfg.voc for p in voc_pairs(d, "train")]
    val_pairs = [p for d in cfg.val for p in tum_pairs(d)]
    if not cfg.val:
        val_pairs = [p for d in cfg.voc for p in voc_pairs(d, "val")] if cfg.voc else []
    if not val_pairs:  # hold out every 10th training frame
        val_pairs, train_pairs = train_pairs[::10], [p for k, p in enumerate(train_pairs) if k % 10]
    train = load_samples(train_pairs, cfg.classes, cfg.size)
    val = load_samples(val_pairs, cfg.classes, cfg.size)
    # Validation needs the exact network size: frames of other aspect ratios are resized.
    for s in val:
        if s.label.shape != (cfg.size[1], cfg.size[0]):
            import cv2

            s.rgb = cv2.resize(s.rgb, cfg.size, interpolation=cv2.INTER_AREA)
            s.label = cv2.resize(s.label, cfg.size, interpolation=cv2.INTER_NEAREST)
    say(f"loaded {len(train)} training and {len(val)} validation frames in {time.perf_counter() - t0:.1f} s")
    aug = Augment(crop=cfg.crop or cfg.size, scale=cfg.scale)
    return SegDataset(train, aug, cfg.seed), SegDataset(val)


def class_frequencies(ds: SegDataset, n: int) -> list[float]:
    counts = np.zeros(n)
    for s in ds.samples:
        counts += np.bincount(s.label[s.label != IGNORE_INDEX].ravel(), minlength=n)[:n]
    return (counts / max(1.0, counts.sum())).tolist()


def _init_from(model: nn.Module, cfg: TrainConfig, say: Callable[[str], None]) -> None:
    """Copy weights from ``cfg.init``; heads missing there (shipped files drop the training-only
    heads) keep their fresh initialisation."""
    from semslam.nets.models import load_checkpoint

    src, meta = load_checkpoint(cfg.init)  # type: ignore[arg-type]
    if (meta["arch"], float(meta["width"]), len(meta["class_ids"])) != (cfg.arch, cfg.width, cfg.classes.n_classes):
        raise ConfigError(f"--init {cfg.init}: {meta['arch']} width {meta['width']} with {len(meta['class_ids'])} "
                          f"classes does not match {cfg.arch} width {cfg.width} with {cfg.classes.n_classes}")
    state = src.state_dict()
    mine = model.state_dict()
    mine.update({k: v for k, v in state.items() if k in mine})
    model.load_state_dict(mine)
    say(f"initialised from {cfg.init} ({meta.get('epochs', '?')} epochs, val mIoU {meta.get('val_miou', float('nan')):.4f})")



def set_poly_lr(opt: torch.optim.Optimizer, step: int, total: int, warm: int, t0: float, minutes: float) -> None:
    """Linear warm-up over ``warm`` steps, then the poly schedule (power 0.9) of the
    segmentation papers, each group scaled from its ``base_lr``. The schedule's position is
    by steps, or by time when a ``minutes`` budget ends training first."""
    done = step / total
    if minutes:
        done = max(done, (time.perf_counter() - t0) / (60 * minutes))
    f = (step + 1) / warm if step < warm else max(0.0, 1 - done) ** 0.9
    for g in opt.param_groups:
        g["lr"] = g["base_lr"] * f

def train(cfg: TrainConfig, progress: bool = True, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Train ``cfg.arch`` and write the checkpoint to ``cfg.out``; return its metadata."""
    cfg.validate()
    torch.set_num_threads(cfg.threads or os.cpu_count() or 1)
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    train_ds, val_ds = build_datasets(cfg, say)
    n = cfg.classes.n_classes
    model = build_model(cfg.arch, n, cfg.width, **cfg.options)
    if cfg.init is not None:
        _init_from(model, cfg, say)
    model.train()
    opt = torch.optim.AdamW(_param_groups(model, cfg.lr, cfg.weight_decay), lr=cfg.lr)
    loader = DataLoader(train_ds, batch_size=cfg.batch, shuffle=True, drop_last=len(train_ds) >= cfg.batch,
                        generator=torch.Generator().manual_seed(cfg.seed))
    total = cfg.epochs * len(loader)
    warm = max(1, int(cfg.warmup * total))
    loss_fn = _loss_fn(cfg.arch)
    meta: dict[str, Any] = {
        "arch": cfg.arch,
        "width": cfg.width,
        "options": dict(cfg.options),
        "class_ids": list(cfg.classes.ids),
        "class_names": list(cfg.classes.names),
        "other_ids": cfg.classes.other,
        "input_size": list(cfg.size),
        "mean": list(MEAN),
        "std": list(STD),
        "train_data": describe_sources(cfg.data, cfg.voc),
        "val_data": describe_sources(cfg.val, []) if cfg.val else "held out from training data",
        "n_train_frames": len(train_ds),
        "n_val_frames": len(val_ds) if val_ds is not None else 0,
        "class_freq_train": class_frequencies(train_ds, n),
        "crop": list(cfg.crop or cfg.size),
        "batch": cfg.batch,
        "lr": cfg.lr,
        "optimizer": "AdamW, warm-up + poly(0.9)",
        "seed": cfg.seed,
        "init": str(cfg.init) if cfg.init else None,
        "command": cfg.command,
        "torch_version": str(torch.__version__),
        "parameters": sum(p.numel() for p in model.parameters()),
        "inference_parameters": model.inference_parameters(),  # type: ignore[operator]
        "history": [],
    }
    t0 = time.perf_counter()
    step, stopped = 0, False
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="it", desc=f"train {cfg.arch}", dynamic_ncols=True)
    try:
        for epoch in range(cfg.epochs):
            run_loss, seen = 0.0, 0
            for x, y in loader:
                set_poly_lr(opt, step, total, warm, t0, cfg.minutes)
                loss, parts = loss_fn(model(x, aux=True), y)  # type: ignore[arg-type]
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                step += 1
                run_loss += float(loss.detach()) * len(x)
                seen += len(x)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(epoch=epoch + 1, loss=f"{float(loss.detach()):.3f}",
                                    **{k: f"{v:.3f}" for k, v in parts.items()})
                if cfg.minutes and time.perf_counter() - t0 > 60 * cfg.minutes:
                    stopped = True
                    break
            ev = evaluate(model, val_ds, n) if val_ds is not None and len(val_ds) else {"miou": float("nan"), "iou": []}
            rec = {"epoch": epoch + 1, "steps": step, "train_loss": run_loss / max(1, seen),
                   "val_miou": ev["miou"], "val_iou": ev["iou"], "seconds": round(time.perf_counter() - t0, 1)}
            meta["history"].append(rec)
            msg = (f"epoch {epoch + 1}/{cfg.epochs}: loss {rec['train_loss']:.4f}, val mIoU {ev['miou']:.4f} "
                   f"(IoU {', '.join(f'{nm} {v:.3f}' for nm, v in zip(cfg.classes.names, ev['iou']) if v is not None)})")
            (bar.write if bar is not None else say)(msg)
            meta.update(epochs=epoch + 1, steps=step, val_miou=ev["miou"], val_iou=ev["iou"],
                        train_seconds=round(time.perf_counter() - t0, 1), stopped_early=stopped)
            save_checkpoint(cfg.out, model, meta, half=cfg.half)
            if stopped:
                (bar.write if bar is not None else say)(f"time limit of {cfg.minutes} min reached: stopping")
                break
    finally:
        if bar is not None:
            bar.close()
    meta["epochs_planned"] = cfg.epochs
    meta["weights_dtype"] = "float16" if cfg.half else "float32"
    save_checkpoint(cfg.out, model, meta, half=cfg.half)
    return meta
