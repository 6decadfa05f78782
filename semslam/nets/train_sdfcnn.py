"""Training SDFCNN on CPU: eq. 21 (lambda = 0.4: cross-entropy + berHu depth), validation with
Tables 8/9's metrics, checkpoint with metadata after every epoch.

The paper trains on NYU with SGD (batch 20, lr 0.1 for 20 epochs then 0.01, 20,000 epochs);
none of that fits a shared 2-core CPU, so this follows ``nets.train``'s recipe instead:
AdamW with linear warm-up then poly(0.9) decay (by time when ``minutes`` ends the run first),
weight decay on conv weights only (``nets.train._param_groups``). Images are trained at
``size``, which is also Layer 0's size, so the network sees frames at the resolution it
will be run at; the loss compares outputs and labels at that size.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader

from semslam.core.labels import NYU40_CLASSES
from semslam.errors import ConfigError
from semslam.eval.dense_metrics import DepthErrors, class_iou, confusion, mean_iou, mean_pixel_accuracy
from semslam.nets.datasets import describe_sources
from semslam.nets.models import build_model, load_checkpoint, save_checkpoint
from semslam.nets.sdf_dataset import N_CLASSES, SdfDataset, class_frequencies, load_folder
from semslam.nets.sdfcnn import IMG_SCALE, LAMBDA, MEAN, PAPER_OUTPUT_SIZE, STD, sdfcnn_loss
from semslam.nets.train import _param_groups, set_poly_lr


@dataclass
class SdfTrainConfig:
    out: Path
    data: list[Path] = field(default_factory=list)  # TUM folders with depth and semantic/ (training)
    val: list[Path] = field(default_factory=list)  # held-out folders (default: every 10th training frame)
    epochs: int = 10
    batch: int = 8
    size: tuple[int, int] = (320, 240)  # (w, h) training size = Layer 0's size
    width: float = 0.5
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup: float = 0.05
    lam: float = LAMBDA
    every: int = 1
    seed: int = 0
    threads: int = 0  # 0 = all cores
    minutes: float = 0.0  # stop (and save) after this long; 0 = no limit
    half: bool = True
    camera: float = 0.0  # share of training samples given a real camera's defects (sdf_dataset.camera_effects)
    init: Path | None = None
    command: str = ""

    def validate(self) -> SdfTrainConfig:
        if not self.data:
            raise ConfigError("train sdfcnn: give at least one --data folder")
        if self.size[0] % 32 or self.size[1] % 16:
            raise ConfigError(f"train sdfcnn: --size {self.size[0]}x{self.size[1]}: width must be a multiple "
                              "of 32 and height of 16")
        if self.epochs < 1 or self.batch < 1:
            raise ConfigError("train sdfcnn: epochs and batch must be >= 1")
        if not 0.05 <= self.width <= 2.0:
            raise ConfigError(f"train sdfcnn: width {self.width} out of range (0.05..2)")
        if not 0.0 <= self.camera <= 1.0:
            raise ConfigError(f"train sdfcnn: camera {self.camera} out of range (0..1)")
        if not 0.0 <= self.lam <= 1.0:
            raise ConfigError(f"train sdfcnn: lambda {self.lam} out of range (0..1)")
        return self


@torch.inference_mode()
def evaluate(model: nn.Module, ds: SdfDataset, batch: int = 4) -> dict[str, Any]:
    """Tables 8/9's metrics of ``model`` on ``ds`` at the dataset's size (train indices)."""
    was_training = model.training
    model.eval()
    conf = np.zeros((N_CLASSES, N_CLASSES), np.int64)
    depth = DepthErrors()
    for x, y, d in DataLoader(ds, batch_size=batch, shuffle=False):
        out = model(x, output_size=(x.shape[-1], x.shape[-2]))
        conf += confusion(y.numpy(), out["seg"].argmax(1).numpy(), N_CLASSES)
        depth.add(out["depth"][:, 0].numpy(), d.numpy())
    model.train(was_training)
    iou = class_iou(conf)
    return {"mpa": mean_pixel_accuracy(conf), "miou": mean_iou(conf),
            "iou": [None if np.isnan(v) else round(float(v), 4) for v in iou], **depth.result()}


def build_datasets(cfg: SdfTrainConfig, say: Callable[[str], None]) -> tuple[SdfDataset, SdfDataset]:
    """Training (flip + jitter) and validation datasets, all at ``cfg.size``."""
    t0 = time.perf_counter()
    train = [s for d in cfg.data for s in load_folder(d, cfg.size, cfg.every)]
    val = [s for d in cfg.val for s in load_folder(d, cfg.size)]
    if not val:  # hold out every 10th training frame
        val, train = train[::10], [s for k, s in enumerate(train) if k % 10]
    say(f"loaded {len(train)} training and {len(val)} validation frames in {time.perf_counter() - t0:.1f} s")
    return SdfDataset(train, augment=True, seed=cfg.seed, camera=cfg.camera), SdfDataset(val)


def train_sdfcnn(cfg: SdfTrainConfig, progress: bool = True, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Train SDFCNN and write the checkpoint to ``cfg.out``; return its metadata."""
    cfg.validate()
    torch.set_num_threads(cfg.threads or os.cpu_count() or 1)
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    train_ds, val_ds = build_datasets(cfg, say)
    options = {"input_size": list(cfg.size), "output_size": list(PAPER_OUTPUT_SIZE)}
    model = build_model("sdfcnn", N_CLASSES, cfg.width, **options)
    if cfg.init is not None:
        src, meta0 = load_checkpoint(cfg.init)
        if meta0["arch"] != "sdfcnn" or float(meta0["width"]) != cfg.width:
            raise ConfigError(f"--init {cfg.init}: {meta0['arch']} width {meta0['width']} is not sdfcnn width {cfg.width}")
        model.load_state_dict(src.state_dict())
    model.train()
    opt = torch.optim.AdamW(_param_groups(model, cfg.lr, cfg.weight_decay), lr=cfg.lr)
    loader = DataLoader(train_ds, batch_size=cfg.batch, shuffle=True, drop_last=len(train_ds) >= cfg.batch,
                        generator=torch.Generator().manual_seed(cfg.seed))
    total = cfg.epochs * len(loader)
    warm = max(1, int(cfg.warmup * total))
    meta: dict[str, Any] = {
        "arch": "sdfcnn", "width": cfg.width, "options": options,
        "class_ids": sorted(NYU40_CLASSES), "class_names": [NYU40_CLASSES[i] for i in sorted(NYU40_CLASSES)],
        "input_size": list(cfg.size), "mean": list(MEAN), "std": list(STD), "img_scale": IMG_SCALE,
        "loss": f"eq. 21: {cfg.lam} * cross-entropy + {1 - cfg.lam:.1f} * berHu(depth residual)",
        "lambda": cfg.lam,
        "train_data": describe_sources(cfg.data, []),
        "val_data": describe_sources(cfg.val, []) if cfg.val else "every 10th training frame",
        "n_train_frames": len(train_ds), "n_val_frames": len(val_ds),
        "class_freq_train": [round(f, 5) for f in class_frequencies(train_ds.samples)],
        "camera_effects": cfg.camera, "batch": cfg.batch, "lr": cfg.lr, "optimizer": "AdamW, warm-up + poly(0.9)", "seed": cfg.seed,
        "init": str(cfg.init) if cfg.init else None, "command": cfg.command, "torch_version": str(torch.__version__),
        "parameters": sum(p.numel() for p in model.parameters()),
        "inference_parameters": sum(p.numel() for p in model.parameters()),
        "history": [],
    }
    t0 = time.perf_counter()
    step, stopped = 0, False
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="it", desc="train sdfcnn", dynamic_ncols=True)
    tell = bar.write if bar is not None else say
    try:
        for epoch in range(cfg.epochs):
            run_loss, seen = 0.0, 0
            for x, y, d in loader:
                set_poly_lr(opt, step, total, warm, t0, cfg.minutes)
                out = model(x, output_size=(x.shape[-1], x.shape[-2]))
                loss, parts = sdfcnn_loss(out, y, d, cfg.lam)
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
            ev = evaluate(model, val_ds)
            rec = {"epoch": epoch + 1, "steps": step, "train_loss": run_loss / max(1, seen),
                   **{k: ev[k] for k in ("mpa", "miou", "rms", "rel", "delta1", "delta2", "delta3")},
                   "seconds": round(time.perf_counter() - t0, 1)}
            meta["history"].append(rec)
            tell(f"epoch {epoch + 1}/{cfg.epochs}: loss {rec['train_loss']:.4f}, val MPA {ev['mpa']:.3f} "
                 f"MIoU {ev['miou']:.3f} RMS {ev['rms']:.3f} m REL {ev['rel']:.3f} delta1 {ev['delta1']:.3f}")
            meta.update(epochs=epoch + 1, steps=step, val=ev, val_miou=ev["miou"],
                        train_seconds=round(time.perf_counter() - t0, 1), stopped_early=stopped)
            save_checkpoint(cfg.out, model, meta, half=cfg.half)
            if stopped:
                tell(f"time limit of {cfg.minutes} min reached: stopping")
                break
    finally:
        if bar is not None:
            bar.close()
    meta["epochs_planned"] = cfg.epochs
    save_checkpoint(cfg.out, model, meta, half=cfg.half)
    return meta
