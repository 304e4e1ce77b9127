"""How a build's traffic moves, beside what is published of NGSIM's: the statistics of the realism
report (`bench/realism.py`), pure functions over tracks tables.

Every statistic is of the tracks table, on its grid (0.2 s by default), per location and over
all: the recorded speed and its change between consecutive steps of a track; the recorded
(longitudinal) acceleration and its change per step (jerk); lateral speed (the change of x); the
recorded space and time headways where there is a leader; density (vehicles in view per km of the
section and per lane, at each step). And rates: lane changes (a change of lane_id between
consecutive steps of a track) per vehicle-minute; the share of time below 5 m/s; the share of rows
whose recorded acceleration is beyond 3 m/s²; the mean over tracks of the share of a track's
steps whose jerk is beyond 15 m/s³ (the data-quality literature's measures of NGSIM's noise).

`noise_measures` gives the second-order statistics that the synthetic generator is tuned to
against a held-out real US-101 sample (docs/synthetic.md), per recording and pooled: the standard
deviations of the heading, of the acceleration, jerk and lateral acceleration taken as finite
differences of the recorded speed and x, and the lane changes per track-step.
Constant velocity's errors, the other half of the report, need the graphs: `bench/realism.py`
computes them with `aigem.runs.baseline`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.statistics import Distribution, describe

ALL = "all"  # the name of the statistics over every location
SLOW_MPS = 5.0  # the share of time below this speed (stop-and-go)
HARD_ACCEL_MPS2 = 3.0  # the share of rows whose recorded acceleration is beyond this
HARD_JERK_MPS3 = 15.0  # the per-track share of steps whose jerk is beyond this
# A lane holds at least this share of a recording's rows to count among its lanes for the density
# (on- and off-ramps, which few rows use, do not).
MIN_LANE_SHARE = 0.02
DISTRIBUTIONS = (
    "speed_mps",
    "speed_change_mps2",
    "accel_mps2",
    "jerk_mps3",
    "lateral_speed_mps",
    "space_headway_m",
    "time_headway_s",
    "density_veh_per_km_lane",
)


@dataclass(frozen=True)
class Realism:
    """The statistics of one location (or of all): a distribution per DISTRIBUTIONS name, and
    the rates (None where there is nothing to count)."""

    distributions: dict[str, Distribution]
    lane_changes_per_vehicle_minute: float | None
    slow_share: float | None  # of rows, below SLOW_MPS
    hard_accel_share: float | None  # of rows, |recorded acceleration| > HARD_ACCEL_MPS2
    hard_jerk_track_share: float | None  # mean over tracks of the share of |jerk| > HARD_JERK_MPS3


def step_values(tracks: pl.LazyFrame, time_step_s: float) -> pl.DataFrame:
    """Per tracks row: location, track, speed, the changes per step of speed, of acceleration
    (jerk) and of x (lateral speed) since the step before (null at a track's first step, the
    jerk at its first two), the recorded acceleration and headways (null without a leader), and
    whether the lane changed since the step before (null at a track's first step).

    Rows of a track are consecutive grid steps (the tracks contract), so differences between
    consecutive rows of a track are differences over one time step.
    """
    per_step = lambda column: pl.col(column).diff().over(s.TRACK_ID) / time_step_s  # noqa: E731
    return (
        tracks.sort(s.TRACK_ID, s.TIME_S)
        .select(
            s.LOCATION,
            s.TRACK_ID,
            s.SPEED_MPS,
            per_step(s.SPEED_MPS).alias("speed_change_mps2"),
            pl.col(s.ACCEL_MPS2).alias("accel_mps2"),
            per_step(s.ACCEL_MPS2).alias("jerk_mps3"),
            per_step(s.X_M).alias("lateral_speed_mps"),
            pl.col(s.SPACE_HEADWAY_M).alias("space_headway_m"),
            pl.col(s.TIME_HEADWAY_S).alias("time_headway_s"),
            (pl.col(s.LANE_ID).diff().over(s.TRACK_ID) != 0).alias("lane_change"),
        )
        .collect(engine="streaming")
    )


def densities(tracks: pl.LazyFrame, time_step_s: float) -> pl.DataFrame:
    """Per recording and grid step: location and vehicles in view per km per lane; the section's
    length is the span of its rows' y, its lanes those holding MIN_LANE_SHARE of its rows."""
    recording = [s.LOCATION, s.PERIOD]
    step = (pl.col(s.TIME_S) / time_step_s).round().cast(pl.Int64).alias("step")
    rows = tracks.select(*recording, s.LANE_ID, s.Y_M, step).collect(engine="streaming")
    length_km = ((pl.col(s.Y_M).max() - pl.col(s.Y_M).min()) / 1000).alias("length_km")
    sections = rows.group_by(recording).agg(length_km)
    share = pl.col("len") / pl.col("len").sum().over(recording)
    lanes = (
        rows.group_by(*recording, s.LANE_ID)
        .len()
        .filter(share >= MIN_LANE_SHARE)
        .group_by(recording)
        .len("lanes")
    )
    per_step = rows.group_by(*recording, "step").len("vehicles")
    density = pl.col("vehicles") / (pl.col("length_km") * pl.col("lanes"))
    return (
        per_step.join(sections, on=recording)
        .join(lanes, on=recording)
        .select(s.LOCATION, density.alias("density_veh_per_km_lane"))
    )


def realism(tracks: pl.LazyFrame, time_step_s: float) -> dict[str, Realism]:
    """The statistics of each location of `tracks` (TRACKS_SCHEMA), and of all (ALL)."""
    values = step_values(tracks, time_step_s)
    density = densities(tracks, time_step_s)
    locations = sorted(values[s.LOCATION].unique().to_list())
    return {
        name: _statistics(
            values if name == ALL else values.filter(pl.col(s.LOCATION) == name),
            density if name == ALL else density.filter(pl.col(s.LOCATION) == name),
            time_step_s,
        )
        for name in [*locations, ALL]
    }


def _statistics(values: pl.DataFrame, density: pl.DataFrame, time_step_s: float) -> Realism:
    columns = {name: values[name] for name in DISTRIBUTIONS[:-1]}
    columns[DISTRIBUTIONS[-1]] = density[DISTRIBUTIONS[-1]]
    minutes = values.height * time_step_s / 60
    jerk = values.drop_nulls("jerk_mps3")
    per_track = jerk.group_by(s.TRACK_ID).agg((pl.col("jerk_mps3").abs() > HARD_JERK_MPS3).mean())
    accel = values["accel_mps2"].drop_nulls()
    return Realism(
        distributions={name: describe(c.drop_nulls().to_numpy()) for name, c in columns.items()},
        lane_changes_per_vehicle_minute=(
            int(values["lane_change"].sum()) / minutes if minutes else None
        ),
        slow_share=_mean(values[s.SPEED_MPS] < SLOW_MPS),
        hard_accel_share=_mean(accel.abs() > HARD_ACCEL_MPS2),
        hard_jerk_track_share=_mean(per_track["jerk_mps3"]),
    )


@dataclass(frozen=True)
class NoiseMeasures:
    """Second-order statistics of a tracks table on its grid (step dt), over the rows where each
    is defined; differences are taken within a track only. Standard deviations are population
    ones (ddof 0); a measure is None where it has no value."""

    heading_std_rad: float | None  # of HEADING_RAD, as the build derives it
    jerk_std_mps3: float | None  # of (v[t+1] - 2 v[t] + v[t-1]) / dt², v the recorded speed
    lateral_accel_std_mps2: float | None  # of (x[t+1] - 2 x[t] + x[t-1]) / dt²
    accel_std_mps2: float | None  # of (v[t+1] - v[t]) / dt
    lane_changes_per_track_step: float | None  # lane_id changes / consecutive row pairs
    rows: int


NOISE_MEASURES = (
    "heading_std_rad",
    "jerk_std_mps3",
    "lateral_accel_std_mps2",
    "accel_std_mps2",
    "lane_changes_per_track_step",
)


def noise_values(tracks: pl.LazyFrame, time_step_s: float) -> pl.DataFrame:
    """Per tracks row: recording ("location/period"), heading, and the finite differences of
    `NoiseMeasures` centred on the row (jerk and lateral acceleration: null at a track's first and
    last row) or forward from it (acceleration and lane change: null at its last row).

    Rows of a track are consecutive grid steps (the tracks contract), so a shift within a track
    is one time step.
    """
    after = lambda c: pl.col(c).shift(-1).over(s.TRACK_ID)  # noqa: E731
    before = lambda c: pl.col(c).shift(1).over(s.TRACK_ID)  # noqa: E731
    second = lambda c: (after(c) - 2 * pl.col(c) + before(c)) / time_step_s**2  # noqa: E731
    return (
        tracks.sort(s.TRACK_ID, s.TIME_S)
        .select(
            pl.concat_str(s.LOCATION, s.PERIOD, separator="/").alias("recording"),
            pl.col(s.HEADING_RAD).alias("heading_rad"),
            second(s.SPEED_MPS).alias("jerk_mps3"),
            second(s.X_M).alias("lateral_accel_mps2"),
            ((after(s.SPEED_MPS) - pl.col(s.SPEED_MPS)) / time_step_s).alias("accel_mps2"),
            (after(s.LANE_ID) != pl.col(s.LANE_ID)).alias("lane_change"),
        )
        .collect(engine="streaming")
    )


def noise_measures(tracks: pl.LazyFrame, time_step_s: float) -> dict[str, NoiseMeasures]:
    """`NoiseMeasures` of each recording of `tracks` (TRACKS_SCHEMA), keyed "location/period",
    and of all rows pooled (ALL)."""
    values = noise_values(tracks, time_step_s)
    names = sorted(values["recording"].unique().to_list())
    return {
        name: _noise(values if name == ALL else values.filter(pl.col("recording") == name))
        for name in [*names, ALL]
    }


def _noise(values: pl.DataFrame) -> NoiseMeasures:
    def std(column: str) -> float | None:
        present = values[column].drop_nulls()
        return float(present.std(ddof=0)) if len(present) else None

    return NoiseMeasures(
        heading_std_rad=std("heading_rad"),
        jerk_std_mps3=std("jerk_mps3"),
        lateral_accel_std_mps2=std("lateral_accel_mps2"),
        accel_std_mps2=std("accel_mps2"),
        lane_changes_per_track_step=_mean(values["lane_change"].drop_nulls()),
        rows=values.height,
    )


def _mean(flags: pl.Series) -> float | None:
    return float(flags.mean()) if len(flags) else None


def distribution_values(tracks: pl.LazyFrame, time_step_s: float) -> dict[str, np.ndarray]:
    """Every value behind each of DISTRIBUTIONS, over all locations: what a plot overlays."""
    values = step_values(tracks, time_step_s)
    density = densities(tracks, time_step_s)
    out = {name: values[name].drop_nulls().to_numpy() for name in DISTRIBUTIONS[:-1]}
    out[DISTRIBUTIONS[-1]] = density[DISTRIBUTIONS[-1]].to_numpy()
    return out
