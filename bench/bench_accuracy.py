"""Benchmark: time to a validation loss, per training setting (batch size, learning rate, schedule,
warm-up, clipping), the figure that chooses each device's defaults (docs/aigem.md).

    python bench/bench_accuracy.py bench/out/graphs-txt-r6-m15 --out bench/out/accuracy-r6 \\
        --target-m2 3.0 --epochs 20
    python bench/bench_accuracy.py BUILD --out DIR --epochs 12 --threads 1 \\
        --setting batch=32 --setting batch=256,lr=3e-3,schedule=cosine,warmup=1,clip=1000

Each --setting (default: SETTINGS) is trained from scratch by `aigem.training.fit.fit` itself, one
after the other, into DIR/<setting> (the 5 s model unless --horizon-s; the same seed; --epochs, or
fewer under --max-minutes). A cosine schedule decays over --epochs: give the epochs that fit the
time rather than a time limit, or the rate is still high when the time runs out. A setting whose
run in DIR has finished (its epochs done, or cut by --max-minutes) is not trained again, so an
interrupted benchmark goes on where it stopped and new settings can be added to a table.

For each setting it prints: the epochs run, the validation MSE (m²) after each, the best, and the
first epoch at or below --target-m2 with the training time to it (train + validation seconds of
the epochs up to it, as fit logs them; start-up excluded) and the graphs seen by then. The time is
what counts; graphs seen show how much of a difference is the batch size's statistical efficiency
(the same on any device) and how much the device's speed at that batch size. DIR/accuracy.png
draws the validation curves against time and against graphs seen; DIR/accuracy.json holds the
table.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from aigem.config import ModelConfig, TrainConfig
from aigem.devices import pick_device
from aigem.figures.pictures import describe_build
from aigem.runs import folder, run_log
from aigem.training.fit import fit

# The settings compared by default: the paper's rate at batch 32, constant and decayed, and at batch
# 256; then batch 256 and 1024 with the rate scaled by about sqrt(batch / 32) and by batch / 32,
# warmed up and decayed. (Gradient norms fall from ~4e4 over the first steps to ~3e3 after two
# epochs, so a fixed clipping norm clips nearly every step or hardly any: it is an option, not in
# the defaults.)
SETTINGS = (
    "batch=32",
    "batch=32,schedule=cosine",
    "batch=256",
    "batch=256,lr=3e-3,schedule=cosine,warmup=1",
    "batch=256,lr=8e-3,schedule=cosine,warmup=2",
    "batch=1024,lr=6e-3,schedule=cosine,warmup=2",
)
KEYS = {  # a setting's words -> TrainConfig fields
    "batch": ("batch_size", int),
    "lr": ("learning_rate", float),
    "schedule": ("lr_schedule", str),
    "warmup": ("warmup_epochs", float),
    "clip": ("clip_grad_norm", float),
}


def parse_setting(text: str, base: TrainConfig) -> TrainConfig:
    """'batch=256,lr=3e-3,schedule=cosine' -> `base` with those fields."""
    fields = {}
    for part in text.split(","):
        key, _, value = part.partition("=")
        if key not in KEYS or not value:
            raise SystemExit(
                f"--setting {text}: {part!r} is not KEY=VALUE, KEY one of {', '.join(KEYS)}"
            )
        name, kind = KEYS[key]
        try:
            fields[name] = kind(value)
        except ValueError:
            raise SystemExit(f"--setting {text}: {value!r} is not a {kind.__name__}") from None
    try:
        return replace(base, **fields)
    except ValueError as err:
        raise SystemExit(f"--setting {text}: {err}") from None


@dataclass(frozen=True)
class Outcome:
    setting: str
    val_m2: list[float]  # after each epoch
    seconds: list[float]  # cumulative train + validation seconds after each epoch
    graphs: list[int]  # cumulative graphs seen after each epoch
    target_epoch: int | None  # first epoch (1-based) at or below the target

    def to_dict(self) -> dict[str, object]:
        at = self.target_epoch
        return {
            "setting": self.setting,
            "epochs": len(self.val_m2),
            "best_val_m2": min(self.val_m2),
            "last_val_m2": self.val_m2[-1],
            "target_epoch": at,
            "seconds_to_target": self.seconds[at - 1] if at else None,
            "graphs_to_target": self.graphs[at - 1] if at else None,
            "val_m2": self.val_m2,
            "seconds": self.seconds,
        }


def outcome(setting: str, run_dir: Path, train_graphs: int, target_m2: float) -> Outcome:
    rows = run_log.read_metrics(run_dir)
    val = [row.val_loss_m2 for row in rows]
    seconds, graphs, total_s, total_graphs = [], [], 0.0, 0
    for row in rows:
        total_s += row.train_seconds + row.val_seconds
        # a time limit may cut an epoch; a row of an older aigem does not say
        total_graphs += row.train_graphs if row.train_graphs is not None else train_graphs
        seconds.append(round(total_s, 1))
        graphs.append(total_graphs)
    reached = next((i for i, v in enumerate(val, start=1) if v <= target_m2), None)
    return Outcome(setting, val, seconds, graphs, reached)


def _finished(run_dir: Path, train: TrainConfig, train_graphs: int) -> bool:
    """Whether the setting's run has all its epochs, or was stopped by the time limit (its last
    epoch cut short, or the logged time over the limit)."""
    rows = run_log.read_metrics(run_dir)
    if not rows or not (run_dir / folder.LAST).is_file():
        return False
    last = rows[-1]
    cut = last.train_graphs is not None and last.train_graphs < train_graphs
    logged_s = sum(r.train_seconds + r.val_seconds for r in rows)
    return last.epoch >= train.epochs or cut or logged_s >= 60 * (train.max_minutes or math.inf)


def run_dir_of(out: Path, setting: str) -> Path:
    """DIR/<setting>: 'batch=256,lr=3e-3' -> DIR/batch256_lr3e-3."""
    return out / setting.replace(",", "_").replace("=", "")


def train_setting(
    build: Path, run_dir: Path, train: TrainConfig, train_graphs: int, device: str
) -> None:
    if _finished(run_dir, train, train_graphs):
        return
    resume = (run_dir / folder.LAST).is_file()
    fit(build, run_dir, ModelConfig(), train, device, resume=resume)


def draw(
    outcomes: list[Outcome], target_m2: float, baseline_m2: float | None, title: str, path: Path
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (by_time, by_graphs) = plt.subplots(
        1, 2, figsize=(12, 4.8), sharey=True, layout="constrained"
    )
    for item in outcomes:
        by_time.plot([s / 60 for s in item.seconds], item.val_m2, marker=".", label=item.setting)
        by_graphs.plot([g / 1e6 for g in item.graphs], item.val_m2, marker=".")
    for axes, label in ((by_time, "training time, min"), (by_graphs, "graphs seen, millions")):
        axes.axhline(target_m2, color="black", linewidth=0.8, label=f"target {target_m2:g} m²")
        if baseline_m2 is not None:
            axes.axhline(baseline_m2, color="grey", linestyle="--", linewidth=0.8,
                         label="constant velocity")  # fmt: skip
        axes.set_xlabel(label)
        axes.set_xlim(left=0)
        axes.grid(alpha=0.3)
    # Linear, from 0: the first epochs' losses, far above, are left out of the picture.
    by_time.set_ylim(0, 2.5 * max(target_m2, baseline_m2 or 0.0))
    by_time.set_ylabel("validation MSE, m²")
    by_time.legend(fontsize=7)
    figure.suptitle(title, fontsize=9)
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("build", type=Path)
    parser.add_argument("--out", type=Path, required=True, help="a directory for the runs")
    parser.add_argument("--setting", action="append", help="repeatable; default: SETTINGS")
    parser.add_argument("--target-m2", type=float, default=3.0)
    parser.add_argument("--horizon-s", type=float, default=5.0)
    parser.add_argument("--epochs", type=int, default=100)
    parser.add_argument("--max-minutes", type=float, help="per setting")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--workers", type=int, help="default: fit's")
    parser.add_argument("--threads", type=int, help="default: fit's")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    device = pick_device(args.device)
    base = TrainConfig(
        horizon_s=args.horizon_s,
        epochs=args.epochs,
        max_minutes=args.max_minutes,
        seed=args.seed,
        workers=args.workers,
        threads=args.threads,
    )
    settings = args.setting or list(SETTINGS)
    trains = [parse_setting(text, base) for text in settings]  # all checked before the first
    gpu = f", {torch.cuda.get_device_name(device)}" if device.type == "cuda" else ""
    print(f"# {args.build} on {device}{gpu} ({platform.node()}); target {args.target_m2:g} m²")
    train_graphs = int(json.loads((args.build / "manifest.json").read_text())["splits"]["train"])
    outcomes = []
    for text, train in zip(settings, trains, strict=True):
        run_dir = run_dir_of(args.out, text)
        train_setting(args.build, run_dir, train, train_graphs, str(device))
        outcomes.append(outcome(text, run_dir, train_graphs, args.target_m2))
        item = outcomes[-1].to_dict()
        reached = (
            f"epoch {item['target_epoch']}, {item['seconds_to_target'] / 60:.1f} min, "
            f"{item['graphs_to_target'] / 1e6:.2f} M graphs"
            if item["target_epoch"]
            else "not reached"
        )
        curve = " ".join(f"{v:.2f}" for v in item["val_m2"])
        print(
            f"{text:<52} {item['epochs']:>3} epochs  best {item['best_val_m2']:.3f}  "
            f"last {item['last_val_m2']:.3f}  target: {reached}\n    val MSE by epoch: {curve}",
            flush=True,
        )
    baseline = run_log.read_baseline(run_dir_of(args.out, settings[0]))
    model = f"the {args.horizon_s:g} s model"
    title = f"validation MSE of {model} on {device}; {describe_build(args.build)}"
    draw(outcomes, args.target_m2, baseline, title, args.out / "accuracy.png")
    table = {"build": str(args.build), "device": str(device), "target_m2": args.target_m2,
             "settings": [o.to_dict() for o in outcomes]}  # fmt: skip
    (args.out / "accuracy.json").write_text(json.dumps(table, indent=2) + "\n")
    print(f"# {args.out / 'accuracy.png'}, {args.out / 'accuracy.json'}")


if __name__ == "__main__":
    main()
