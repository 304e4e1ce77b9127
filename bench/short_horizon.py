"""Why a trained AiGem trails constant velocity at short horizons: measurements of runs.

    .venv/bin/python bench/short_horizon.py RUN [RUN ...] [--split test] [--json OUT]

RUN is a run directory (of a multi-horizon run, a member: RUN/h1s). For each run, on its own
build and with its own scaler, the script prints:

1. **The scaled inputs.** What share of its target range each present-state feature of the
   targets occupies (from the 1st to the 99th percentile), constant velocity's displacement over
   one 0.2 s step and its error at 1 s, both in the scaled units the decoder predicts in: the
   precision the output MLP needs.
2. **The first steps.** The pooled RMSE (m) at each of the first five 0.2 s steps, the model's
   and constant velocity's, on the same targets.
3. **What the encoder passes on.** A linear probe (least squares with an intercept, fitted on
   the validation split, scored on --split) of each target's present velocity (vx lateral, vy
   along the road, m/s) from its present-step embedding (the decoder's only input besides the
   position), beside the same probe from its scaled present features and the velocity's own
   spread. Times 1 s, a probe's error is the error at 1 s of a decoder that reads the velocity
   from the embedding linearly.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from aigem.model.data import XY, Collate, GraphDataset, run_scaler, xy_to_metres
from aigem.model.network import AiGem
from aigem.runs.baseline import constant_velocity
from aigem.runs.checkpoints import load_model
from aigem.runs.records import BEST
from aigem.runs.refusals import resolve_build
from ngsim_graphs.scaling import FEATURES, MinMaxScaler

FIRST_STEPS = 5  # 0.2 s .. 1 s


@dataclass(frozen=True)
class Targets:
    """Per target of a split: its scaled present features, its present-step embedding, its
    velocity (m/s) and the squared errors (m^2) of the model and of constant velocity."""

    features: np.ndarray  # (A, 4) scaled
    embedding: np.ndarray  # (A, H)
    velocity: np.ndarray  # (A, 2)
    cv_step: np.ndarray  # (A, 2) scaled
    cv_error_1s_scaled: np.ndarray  # (A,) valid targets only
    model_sq: np.ndarray  # (A, FIRST_STEPS)
    cv_sq: np.ndarray
    mask: np.ndarray  # (A, FIRST_STEPS)


def targets_of(
    model: AiGem, scaler: MinMaxScaler, build: Path, split: str, batch_size: int = 64
) -> Targets:
    """Run `model` over `split` of `build`, keeping what the report needs."""
    model.eval()
    dataset = GraphDataset(build, split, model.config.history_steps_read, scaler)
    collate = Collate(scaler, layers=model.config.layers)
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, collate_fn=collate)
    steps = min(FIRST_STEPS, model.config.future_steps)
    parts: dict[str, list[np.ndarray]] = {name: [] for name in Targets.__dataclass_fields__}
    dt = dataset.config.time_step_s
    with torch.no_grad():
        for batch in loader:
            target = batch.target_node
            # the present-step embeddings the decoder starts from
            z = model.encode(batch)
            predicted = xy_to_metres(scaler, model(batch, steps)).numpy().astype(np.float64)
            state = batch.target_state.numpy().astype(np.float64)
            cv = constant_velocity(state, steps, dt)
            truth = batch.target_xy[:, :steps].numpy().astype(np.float64)
            mask = batch.target_mask[:, :steps].numpy()
            heading, speed = state[:, 2], state[:, 3]
            parts["features"].append(batch.x[target].numpy())
            parts["embedding"].append(z.numpy())
            parts["velocity"].append(
                speed[:, None] * np.stack([np.sin(heading), np.cos(heading)], 1)
            )
            parts["cv_step"].append(collate.cv_step(state, dt))
            parts["model_sq"].append(((predicted - truth) ** 2).sum(-1))
            parts["cv_sq"].append(((cv - truth) ** 2).sum(-1))
            parts["mask"].append(mask)
            scaled_error = _scaled(scaler, cv[:, -1]) - _scaled(scaler, truth[:, -1])
            parts["cv_error_1s_scaled"].append(np.linalg.norm(scaled_error, axis=1)[mask[:, -1]])
    return Targets(**{name: np.concatenate(values) for name, values in parts.items()})


def _scaled(scaler: MinMaxScaler, xy_m: np.ndarray) -> np.ndarray:
    return np.stack([scaler.scale(name, xy_m[:, i]) for i, name in enumerate(XY)], axis=1)


def probe_rmse(train_x: np.ndarray, train_y: np.ndarray, x: np.ndarray, y: np.ndarray) -> list:
    """RMSE per output column of a least-squares linear map (with intercept) fitted on train."""
    design = lambda a: np.hstack([a.astype(np.float64), np.ones((len(a), 1))])  # noqa: E731
    weights, *_ = np.linalg.lstsq(design(train_x), train_y, rcond=None)
    return np.sqrt(((design(x) @ weights - y) ** 2).mean(axis=0)).tolist()


@dataclass(frozen=True)
class Report:
    run: str
    split: str
    targets: int
    occupied_share: dict[str, float]  # feature -> share of its target range, p1..p99
    cv_step_scaled_median: float
    cv_error_1s_scaled_median: float
    rmse_by_step_m: dict[str, list[float]]  # "model", "constant velocity": 0.2 .. 1 s
    velocity_std_mps: list[float]  # vx, vy
    probe_embedding_rmse_mps: list[float]
    probe_features_rmse_mps: list[float]


def report(run: Path, split: str) -> Report:
    model, info = load_model(run, "cpu")
    scaler = run_scaler(info.build.scaler, run / BEST)
    build = resolve_build(info, None)
    scored, fitted = (targets_of(model, scaler, build, name) for name in (split, "val"))
    occupied = {}
    for i, name in enumerate(FEATURES):
        low, high = np.percentile(scored.features[:, i], [1, 99])
        to_low, to_high = scaler.target[name]
        occupied[name] = float((high - low) / (to_high - to_low))
    valid = scored.mask
    rmse = {
        "model": np.sqrt((scored.model_sq * valid).sum(0) / valid.sum(0)).tolist(),
        "constant velocity": np.sqrt((scored.cv_sq * valid).sum(0) / valid.sum(0)).tolist(),
    }
    return Report(
        run=str(run),
        split=split,
        targets=len(scored.velocity),
        occupied_share=occupied,
        cv_step_scaled_median=float(np.median(np.linalg.norm(scored.cv_step, axis=1))),
        cv_error_1s_scaled_median=float(np.median(scored.cv_error_1s_scaled)),
        rmse_by_step_m=rmse,
        velocity_std_mps=scored.velocity.std(axis=0).tolist(),
        probe_embedding_rmse_mps=probe_rmse(
            fitted.embedding, fitted.velocity, scored.embedding, scored.velocity
        ),
        probe_features_rmse_mps=probe_rmse(
            fitted.features, fitted.velocity, scored.features, scored.velocity
        ),
    )


def print_report(result: Report) -> None:
    print(f"{result.run} ({result.split} split, {result.targets:,} targets)")
    shares = ", ".join(f"{name} {share:.0%}" for name, share in result.occupied_share.items())
    print(f"  present state, share of its scaled range (p1..p99): {shares}")
    print(
        f"  constant velocity's 0.2 s step: {result.cv_step_scaled_median:.4f} scaled units "
        f"(median); its error at 1 s: {result.cv_error_1s_scaled_median:.4f}"
    )
    print("  RMSE (m) at 0.2, 0.4, 0.6, 0.8, 1.0 s:")
    for name, values in result.rmse_by_step_m.items():
        print(f"    {name:<18}" + "".join(f"{v:8.3f}" for v in values))
    print("  present velocity (vx, vy), m/s:")
    for name, values in (
        ("spread (std)", result.velocity_std_mps),
        ("probe: embedding", result.probe_embedding_rmse_mps),
        ("probe: features", result.probe_features_rmse_mps),
    ):
        print(f"    {name:<18}" + "".join(f"{v:8.3f}" for v in values))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--split", default="test")
    parser.add_argument("--json", type=Path, help="write the reports' values here")
    args = parser.parse_args(argv)
    results = []
    for run in args.runs:
        results.append(report(run, args.split))
        print_report(results[-1])
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in results], indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
