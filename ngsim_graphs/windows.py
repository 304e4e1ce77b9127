"""Ego windows: the samples of a build, as (ego track, start step) with the ego's present position.

A protocol (`schema.Protocol`) decides which windows a recording gives, and how they are split:
a `SampleProtocol`, chosen by `protocols.PROTOCOLS`. The aigem protocol (AIGEM, here) cuts
K_H + K_F consecutive grid steps of each track at a fixed stride (`ego_windows`) and splits
them by `splits.assign_splits`; the cs-lstm protocol (`cslstm.CS_LSTM`) takes CS-LSTM's kept
rows on the grid.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.manifest import ScriptRows
from ngsim_graphs.sources.contract import RecordingKey
from ngsim_graphs.splits import VehicleIds, assign_splits


def ego_windows(nodes: pl.DataFrame | pl.LazyFrame, config: BuildConfig) -> pl.DataFrame:
    """Every window of every track of one recording's grid nodes (GRID_NODE_SCHEMA, in any
    order; a lazy table is streamed, never held whole).

    A track of n steps starting at step f yields windows starting at f, f + stride, ... while the
    whole window (window_steps steps) lies inside the track. Tracks are contiguous on the grid, so
    the ego is present at every step of each window. Returns one row per window: ego track,
    ego vehicle, start step, present step and the ego's present position (the sample's origin),
    sorted by (ego track, start step).
    """
    nodes = nodes.lazy()
    per_track = nodes.group_by(s.TRACK_ID).agg(
        pl.col(s.VEHICLE_ID).first(),
        pl.col(s.STEP).min().alias("first"),
        pl.len().cast(pl.Int64).alias("n"),  # signed: short tracks give negative counts
    )
    counts = ((pl.col("n") - config.window_steps) // config.stride_steps + 1).clip(lower_bound=0)
    windows = (
        per_track.with_columns(counts.alias("count"))
        .filter(pl.col("count") > 0)
        .with_columns(pl.int_ranges(0, pl.col("count")).alias("index"))
        .explode("index")
        .select(
            pl.col(s.TRACK_ID).alias(s.EGO_TRACK_ID),
            pl.col(s.VEHICLE_ID).alias(s.EGO_VEHICLE_ID),
            (pl.col("first") + pl.col("index") * config.stride_steps)
            .cast(pl.Int32)
            .alias(s.START_STEP),
        )
        .with_columns((pl.col(s.START_STEP) + config.history_steps - 1).alias(s.PRESENT_STEP))
        .collect(engine="streaming")
    )
    origin = nodes.select(
        pl.col(s.TRACK_ID).alias(s.EGO_TRACK_ID),
        pl.col(s.STEP).alias(s.PRESENT_STEP),
        pl.col(s.X_M).alias(s.ORIGIN_X_M),
        pl.col(s.Y_M).alias(s.ORIGIN_Y_M),
    )
    # Each window's present step is one row of its track: the windows, the smaller side, are
    # hashed and every grid node looked up in them (the nodes hashed would take more memory).
    found = origin.join(windows.lazy(), on=[s.EGO_TRACK_ID, s.PRESENT_STEP], how="inner")
    found = found.collect(engine="streaming")
    if found.height != windows.height:
        raise ValueError("a window's ego track has no grid node at its present step")
    return found.select(*windows.columns, s.ORIGIN_X_M, s.ORIGIN_Y_M).sort(
        s.EGO_TRACK_ID, s.START_STEP
    )


@dataclass(frozen=True)
class RecordingWindows:
    """A recording's samples as a protocol makes them."""

    windows: pl.DataFrame  # ego windows (`ego_windows`' columns) with s.SPLIT
    vehicle_ids: VehicleIds  # what the vehicle split took of its Vehicle_IDs
    script_rows: ScriptRows | None = None  # the cs-lstm protocol's rows (None: aigem)


@dataclass(frozen=True)
class SampleProtocol:
    """Which samples a build makes of each recording (`schema.Protocol`): three functions.

    recording_windows(nodes, raw, key, recording_index, config) -> RecordingWindows: the split
        windows of one recording's grid nodes (GRID_NODE_SCHEMA, in any order; a lazy table is
        streamed); `raw` is the recording's staged rows before cleaning, lazy (scanned from its
        files), for a protocol that reads them
    refuses(key) -> why the protocol cannot take recording `key`, or None
    why_no_samples(script_rows, rows, config) -> why the recordings (of `rows` raw rows in all)
        gave no sample, where the protocol can tell; None to leave it to the build
    locations: the only locations it reads, its reason in words (none: any location)
    """

    recording_windows: Callable[
        [pl.DataFrame | pl.LazyFrame, pl.LazyFrame, RecordingKey, int, BuildConfig],
        RecordingWindows,
    ]
    refuses: Callable[[RecordingKey], str | None]
    why_no_samples: Callable[[ScriptRows | None, int, BuildConfig], str | None]
    locations: tuple[tuple[str, ...], str] | None = None


def aigem_windows(
    nodes: pl.DataFrame | pl.LazyFrame,
    raw: pl.LazyFrame,
    key: RecordingKey,
    recording_index: int,
    config: BuildConfig,
) -> RecordingWindows:
    """Every ego window of the recording (`ego_windows`), split by `splits.assign_splits`; the
    vehicle split cuts at the largest Vehicle_ID of its tracks, strays left out (`raw` is not
    read)."""
    ids = nodes.lazy().select(pl.col(s.VEHICLE_ID).unique()).collect(engine="streaming")
    vehicle_ids = VehicleIds.of(ids[s.VEHICLE_ID].to_numpy(), strays_allowed=True)
    windows = ego_windows(nodes, config)
    split = assign_splits(windows, vehicle_ids.largest, recording_index, config)
    return RecordingWindows(split, vehicle_ids)


def _takes_every_recording(key: RecordingKey) -> str | None:
    return None


def _no_reason(script_rows: ScriptRows | None, rows: int, config: BuildConfig) -> str | None:
    return None


AIGEM = SampleProtocol(aigem_windows, _takes_every_recording, _no_reason)
