"""Benchmark: how realistic a build's traffic is, beside the figures published of NGSIM.

    python bench/realism.py BUILD                    # one build's report
    python bench/realism.py BUILD OTHER --plot P.png # two builds, their distributions overlaid

Prints, for every location of each build and over all of them: constant velocity's errors (RMSE
at 1..5 s, pooled over every valid target of every split, the project's metric; ADE and FDE), and
the kinematics of the tracks tables (`ngsim_graphs.realism`): speed, longitudinal acceleration,
jerk, lateral speed, space and time headway, density, lane changes per vehicle-minute, the share of
time below 5 m/s. Beside each, the figure published of NGSIM where one exists, with its source
(`PUBLISHED`), and constant velocity's error against the published one at each horizon. Then the
five second-order measures the synthetic generator is tuned to (`ngsim_graphs.realism.
noise_measures`: the standard deviations of heading, jerk, lateral acceleration and acceleration,
and lane changes per track-step), per recording and pooled, beside a held-out real US-101
sample's (`REAL_US101`) and their ratio to it. With two builds (a user's real build against
synthetic, say) it draws their distributions overlaid in one PNG (--plot, default
bench/out/realism.png). --json writes the report's values.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from aigem.runs.baseline import CHUNK_SAMPLES, constant_velocity
from ngsim_graphs.build import OpenBuild, open_build
from ngsim_graphs.realism import (
    ALL,
    DISTRIBUTIONS,
    NOISE_MEASURES,
    NoiseMeasures,
    Realism,
    distribution_values,
    noise_measures,
    realism,
)
from ngsim_graphs.splits import SPLIT_ORDER

HORIZONS_S = (1, 2, 3, 4, 5)


@dataclass(frozen=True)
class Published:
    """A figure published of NGSIM US-101 and I-80: a value or a (low, high) range."""

    low: float
    high: float
    source: str


# Constant velocity on the CS-LSTM samples of NGSIM US-101 + I-80 (pooled RMSE, as ours).
CS_LSTM_TABLE = "Deo and Trivedi 2018, Convolutional Social Pooling, CVPR-W, Table 1, CV row"
PUBLISHED: dict[str, Published] = {
    **{
        f"cv_rmse_{h}s_m": Published(v, v, CS_LSTM_TABLE)
        for h, v in zip(HORIZONS_S, (0.73, 1.78, 3.13, 4.78, 6.68), strict=True)
    },
    # Raw US-101, every 10 Hz row's v_Acc (a measurement of the data, not peer reviewed).
    "hard_accel_share": Published(
        0.0899, 0.0899, "El-Ballouli, NGSIM US-101 trajectory dataset smoothing (README): 8.99 %"
    ),
    # Raw I-80 at 10 Hz, per trajectory: mean 22.83 %, from 4.70 % to 69.23 %. Ours are at the
    # build's 0.2 s step, where the jerk of noise is about half of that at 0.1 s.
    "hard_jerk_track_share": Published(
        0.047, 0.6923, "J. Adv. Transp. 2023, 2661136 (adaptive Kalman denoising), Table 2"
    ),
}


# A held-out real US-101 sample measured by the project (three recordings, 214 K rows of the
# build's tracks table at 0.2 s) with `noise_measures`: the second-order figures the synthetic
# generator is tuned to (docs/synthetic.md). A measurement of real data, not a published figure.
REAL_US101: dict[str, float] = {
    "heading_std_rad": 0.028,
    "jerk_std_mps3": 8.1,
    "lateral_accel_std_mps2": 0.90,
    "accel_std_mps2": 1.74,
    "lane_changes_per_track_step": 0.0039,
}


@dataclass(frozen=True)
class ConstantVelocity:
    """Constant velocity's errors (m) over every valid target of every split of a build."""

    rmse_m: dict[int, float]  # horizon s -> RMSE at future step horizon / time step
    ade_m: float
    fde_m: float
    targets: int


def constant_velocity_errors(build: OpenBuild) -> dict[str, ConstantVelocity]:
    """Constant velocity's errors per location of `build` and over all (ALL)."""
    config = build.config
    steps = config.future_steps
    locations = [entry.location for entry in build.entries]
    names = sorted(set(locations))
    squared = {name: np.zeros(steps) for name in [*names, ALL]}  # per future step
    euclid = {name: np.zeros(steps) for name in [*names, ALL]}
    valid = {name: np.zeros(steps) for name in [*names, ALL]}
    targets = dict.fromkeys([*names, ALL], 0)
    for split in SPLIT_ORDER:
        size = int(build.manifest.splits[split.value])
        recording = np.asarray(build.sample_arrays(split)["recording_index"])
        for first in range(0, size, CHUNK_SAMPLES):
            ids = np.arange(first, min(first + CHUNK_SAMPLES, size))
            batch = build.graphs(split, ids, first_step=config.history_steps - 1)
            state = batch.node_features[batch.target_node]
            predicted = constant_velocity(state, steps, config.time_step_s)
            error = np.linalg.norm(predicted - batch.target_xy, axis=-1)  # (A, K)
            mask = batch.target_mask
            where = np.array(locations)[recording[ids][batch.node_sample[batch.target_node]]]
            for name in [*names, ALL]:
                mine = slice(None) if name == ALL else where == name
                squared[name] += (error[mine] ** 2 * mask[mine]).sum(axis=0)
                euclid[name] += (error[mine] * mask[mine]).sum(axis=0)
                valid[name] += mask[mine].sum(axis=0)
                targets[name] += int(mask[mine].any(axis=1).sum())
    per_step = round(1 / config.time_step_s)
    return {
        name: ConstantVelocity(
            rmse_m={
                h: float(np.sqrt(squared[name][h * per_step - 1] / valid[name][h * per_step - 1]))
                for h in HORIZONS_S
                if h * per_step <= steps
            },
            ade_m=float(euclid[name].sum() / valid[name].sum()),
            fde_m=float(euclid[name][-1] / valid[name][-1]),
            targets=targets[name],
        )
        for name in [*names, ALL]
        if valid[name].sum()
    }


@dataclass(frozen=True)
class Report:
    """One build's realism: constant velocity's errors and the kinematics, per location."""

    build: str
    constant_velocity: dict[str, ConstantVelocity]
    kinematics: dict[str, Realism]
    noise: dict[str, NoiseMeasures]  # per recording ("location/period") and ALL

    def rows(self, name: str) -> dict[str, float | None]:
        """Every figure of location `name` (or ALL) by the names the table prints."""
        cv, kin = self.constant_velocity.get(name), self.kinematics[name]
        figures: dict[str, float | None] = {}
        for h in HORIZONS_S:
            figures[f"cv_rmse_{h}s_m"] = cv.rmse_m.get(h) if cv else None
        figures["cv_ade_m"] = cv.ade_m if cv else None
        figures["cv_fde_m"] = cv.fde_m if cv else None
        for quantity in DISTRIBUTIONS:
            shown = kin.distributions[quantity]
            for field in ("mean", "std", "p5", "p50", "p95"):
                figures[f"{quantity} {field}"] = getattr(shown, field)
        figures["lane_changes_per_vehicle_minute"] = kin.lane_changes_per_vehicle_minute
        figures["share_below_5_mps"] = kin.slow_share
        figures["hard_accel_share"] = kin.hard_accel_share
        figures["hard_jerk_track_share"] = kin.hard_jerk_track_share
        return figures


def report(build_dir: Path) -> Report:
    build = open_build(build_dir)
    return Report(
        build=str(build_dir),
        constant_velocity=constant_velocity_errors(build),
        kinematics=realism(build.tracks(), build.config.time_step_s),
        noise=noise_measures(build.tracks(), build.config.time_step_s),
    )


def _cell(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}" if abs(value) < 100 else f"{value:,.0f}"


def print_table(reports: list[Report]) -> None:
    """One row per figure: each build's locations and ALL, then the published figure."""
    columns = [(r, name) for r in reports for name in r.kinematics]
    header = ["figure", *(f"{Path(r.build).name}:{name}" for r, name in columns), "NGSIM"]
    lines = [header]
    for figure in reports[0].rows(ALL):
        published = PUBLISHED.get(figure)
        shown = (
            "-"
            if published is None
            else _cell(published.low)
            if published.low == published.high
            else f"{_cell(published.low)}-{_cell(published.high)}"
        )
        lines.append([figure, *(_cell(r.rows(name)[figure]) for r, name in columns), shown])
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    for line in lines:
        print(
            "  ".join(
                cell.rjust(w) if i else cell.ljust(w)
                for i, (cell, w) in enumerate(zip(line, widths, strict=True))
            )
        )
    sources = sorted({p.source for p in PUBLISHED.values()})
    print("\nNGSIM figures: " + "; ".join(sources))


def print_constant_velocity(report_: Report) -> None:
    """Constant velocity's RMSE over all of a build beside the published row, and how far off."""
    errors = report_.constant_velocity.get(ALL)
    print(f"\nconstant velocity, RMSE (m), {Path(report_.build).name}, against {CS_LSTM_TABLE}:")
    for h in HORIZONS_S:
        published = PUBLISHED[f"cv_rmse_{h}s_m"].low
        ours = errors.rmse_m.get(h) if errors else None
        off = "-" if ours is None else f"{100 * (ours / published - 1):+.1f} %"
        print(f"  {h} s  {_cell(ours):>6}  published {published:<5}  off by {off}")


def print_noise(report_: Report) -> None:
    """The five second-order measures per recording and pooled: value (ratio to the real
    US-101 sample's, REAL_US101)."""
    names = list(report_.noise)
    header = ["measure", "real US-101", *names]
    lines = [header]
    for measure in NOISE_MEASURES:
        real = REAL_US101[measure]
        cells = []
        for name in names:
            value = getattr(report_.noise[name], measure)
            cells.append("-" if value is None else f"{value:.3g} ({value / real:.2f})")
        lines.append([measure, f"{real:g}", *cells])
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    print(
        f"\nsecond-order measures, {Path(report_.build).name}: value (ratio to the real sample's)"
    )
    for line in lines:
        print(
            "  ".join(
                c.rjust(w) if i else c.ljust(w)
                for i, (c, w) in enumerate(zip(line, widths, strict=True))
            )
        )
    print(
        "real US-101 sample: held out, three recordings, 214 K rows, measured by the project "
        "(not a published figure)"
    )


def plot(build_dirs: list[Path], reports: list[Report], path: Path) -> None:
    """The builds' distributions overlaid, and constant velocity's RMSE per horizon."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    values = [
        distribution_values(open_build(d).tracks(), open_build(d).config.time_step_s)
        for d in build_dirs
    ]
    fig, axes = plt.subplots(2, 4, figsize=(16, 7.5))
    for ax, quantity in zip(axes.flat, DISTRIBUTIONS, strict=False):
        low, high = np.percentile(np.concatenate([v[quantity] for v in values]), [0.5, 99.5])
        for report_, value in zip(reports, values, strict=True):
            ax.hist(
                value[quantity],
                bins=60,
                range=(low, high),
                density=True,
                histtype="step",
                label=Path(report_.build).name,
            )
        ax.set_title(quantity)
    ax = axes.flat[-1]
    for report_ in reports:
        rmse = report_.constant_velocity[ALL].rmse_m
        ax.plot(list(rmse), list(rmse.values()), "o-", label=Path(report_.build).name)
    ax.plot(
        HORIZONS_S,
        [PUBLISHED[f"cv_rmse_{h}s_m"].low for h in HORIZONS_S],
        "k*--",
        label="NGSIM (Deo and Trivedi 2018)",
    )
    ax.set(title="constant velocity RMSE (m)", xlabel="horizon (s)")
    axes.flat[0].legend()
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("builds", nargs="+", type=Path, metavar="BUILD")
    parser.add_argument("--plot", type=Path, default=Path("bench/out/realism.png"))
    parser.add_argument("--json", type=Path, help="write the report's values here")
    args = parser.parse_args(argv)
    if len(args.builds) > 2:
        parser.error("one or two builds")
    reports = [report(d) for d in args.builds]
    print_table(reports)
    for report_ in reports:
        print_constant_velocity(report_)
        print_noise(report_)
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in reports], indent=2, default=str))
    if len(reports) == 2:
        plot(args.builds, reports, args.plot)
        print(f"distributions overlaid: {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
