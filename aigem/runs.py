"""The run directory of `aigem fit`: every path in it, checkpoints, the log and the curves.

    RUN/run.json        what was trained on what: build, its config hash, model and train configs
    RUN/metrics.jsonl   one line per epoch: train and validation loss (metres^2), best so far
    RUN/last.pt         model, optimizer and progress after the last finished epoch (resume)
    RUN/best.pt         the model of the epoch with the lowest validation loss
    RUN/curves.png      training and validation loss per epoch

Checkpoints are written to a temporary name and renamed, so a kill never leaves a torn file.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from aigem.config import ModelConfig, TrainConfig
from aigem.model import AiGem
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.layout import read_manifest

RUN_INFO, METRICS, LAST, BEST, CURVES = "run.json", "metrics.jsonl", "last.pt", "best.pt", "curves.png"


@dataclass(frozen=True)
class RunState:
    next_epoch: int = 0
    best_epoch: int = -1
    best_val_loss: float = math.inf


def _save_atomic(payload: dict[str, Any], path: Path) -> None:
    partial = path.with_suffix(path.suffix + ".partial")
    torch.save(payload, partial)
    os.replace(partial, path)


def start_run(
    run_dir: Path, build_dir: Path, model_config: ModelConfig, train: TrainConfig, resume: bool,
    model: nn.Module, optimizer: torch.optim.Optimizer, is_writer: bool,
) -> RunState:  # fmt: skip
    """Start a fresh run, or load the last checkpoint into `model` and `optimizer` to resume."""
    manifest = read_manifest(build_dir)
    info = {
        "build_dir": str(Path(build_dir).resolve()),
        "build_config_hash": manifest["config_hash"],
        "model": model_config.to_dict(),
        "train": train.to_dict(),
    }
    last = run_dir / LAST
    if resume:
        if not last.is_file():
            raise NgsimInputError(run_dir, f"nothing to resume: no {LAST}")
        checkpoint = torch.load(last, map_location="cpu", weights_only=False)
        if checkpoint["info"]["model"] != info["model"] or checkpoint["info"]["build_config_hash"] != info["build_config_hash"]:
            raise NgsimInputError(run_dir, "cannot resume: the model config or the build differs from the run's")
        model.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        return RunState(**checkpoint["state"])
    if last.exists() or (run_dir / METRICS).exists():
        raise NgsimInputError(run_dir, "already holds a run; pass --resume to continue it, or choose another --out")
    if is_writer:
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / RUN_INFO).write_text(json.dumps(info, indent=2) + "\n")
    return RunState()


def end_epoch(
    run_dir: Path, state: RunState, epoch: int, train_loss: float, val_loss: float,
    model: nn.Module, optimizer: torch.optim.Optimizer, is_writer: bool,
    timing: dict[str, float] | None = None,
) -> tuple[RunState, dict[str, float]]:  # fmt: skip
    """Log the epoch (with `timing`, e.g. seconds and graphs/s), keep the best model, and
    checkpoint; returns the new state and the metrics row."""
    better = math.isfinite(val_loss) and val_loss < state.best_val_loss
    new = RunState(
        next_epoch=epoch + 1,
        best_epoch=epoch if better else state.best_epoch,
        best_val_loss=val_loss if better else state.best_val_loss,
    )
    row = {
        "epoch": epoch + 1, "train_loss_m2": train_loss, "val_loss_m2": val_loss,
        "best_epoch": new.best_epoch + 1, **(timing or {}),
    }  # fmt: skip
    if not is_writer:
        return new, row
    info = json.loads((run_dir / RUN_INFO).read_text())
    if better:
        _save_atomic({"info": info, "model": model.state_dict(), "epoch": epoch}, run_dir / BEST)
    with (run_dir / METRICS).open("a") as log:
        log.write(json.dumps(row) + "\n")
    checkpoint = {"info": info, "model": model.state_dict(), "optimizer": optimizer.state_dict(), "state": asdict(new)}
    _save_atomic(checkpoint, run_dir / LAST)
    return new, row


def read_metrics(run_dir: Path) -> list[dict[str, float]]:
    path = run_dir / METRICS
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []


def load_model(run_dir: Path, device: torch.device | str = "cpu") -> tuple[AiGem, dict[str, Any]]:
    """The best model of a run and its run info."""
    path = run_dir / BEST
    if not path.is_file():
        raise NgsimInputError(run_dir, f"not a finished run: no {BEST}")
    checkpoint = torch.load(path, map_location=device, weights_only=False)
    model = AiGem(ModelConfig(**checkpoint["info"]["model"]))
    model.load_state_dict(checkpoint["model"])
    return model.to(device).eval(), checkpoint["info"]


def plot_curves(run_dir: Path) -> Path | None:
    """Training and validation loss per epoch as a PNG; None before the first epoch."""
    rows = read_metrics(run_dir)
    if not rows:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [r["epoch"] for r in rows]
    figure, axes = plt.subplots(figsize=(6, 4))
    axes.plot(epochs, [r["train_loss_m2"] for r in rows], marker="o", label="train")
    axes.plot(epochs, [r["val_loss_m2"] for r in rows], marker="o", label="validation")
    axes.set(xlabel="epoch", ylabel="MSE (m²)", title="AiGem training", yscale="log")
    axes.legend()
    figure.tight_layout()
    figure.savefig(run_dir / CURVES, dpi=120)
    plt.close(figure)
    return run_dir / CURVES
