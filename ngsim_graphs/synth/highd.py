"""The simulated recordings in highD's format (`ngsim-graphs synth --format highd`), as tables.

The traffic is `formats.simulated_rows`' (NGSIM feet, 10 Hz); this module turns one recording's
rows into the three tables of a highD recording (`formats` writes them): `NN_tracks.csv`,
`NN_tracksMeta.csv`, `NN_recordingMeta.csv`, NN = 01.. in synth's order of recordings.

- **Time.** highD frame f shows simulated frame n = (f - 5) / 2.5: frames on the 0.2 s grid
  (f = 5, 10, ...) carry exactly the simulated states of the even NGSIM frames n = 0, 2, ...
  (f = 5 is the first frame on highD's grid; highD counts frames from 1), and the frames between
  are linear interpolations of position, speed and acceleration between consecutive simulated
  frames (the other values are the earlier frame's). Nothing is interpolated across a gap. A
  highD build's grid step k is therefore the NGSIM build's step k - 1: time_s is 0.2 s later.
- **Space.** Recordings alternate directions: the 1st, 3rd, ... drive on the lower lanes
  towards +x (drivingDirection 2), the others on the upper lanes towards -x (1). The image has
  both carriageways, `lanes` lanes each, TOP_M below its top edge and MEDIAN_M apart; Local_X is
  measured from the median-side marking, Local_Y from IMAGE_MARGIN_M inside the image's upstream
  edge. (x, y) is the bounding box's upper-left corner, `width` the vehicle's length, `height`
  its width; lanes are numbered from the top of the image as highD does (2.. on the upper
  carriageway, lanes + 3.. on the lower). The highD reader maps all this back to Local_X and
  Local_Y (plus a constant along y).
- **Values.** Metres, m/s, m/s^2, written with DECIMALS decimals (real exports carry 2: at 2, a
  speed of 6.56 ft/s = 1.9995 m/s would read 2.00 and cross the 2 m/s heading hold). The
  simulation has no lateral speed: yVelocity and yAcceleration are 0, so speed = |xVelocity| is
  v_Vel. dhw/thw are NGSIM's Space_Headway/Time_Headway (0: no leader), ttc follows from the
  leader's speed; the left/right neighbour ids are 0 (not derived). Class: Truck for v_Class 3,
  else Car (highD has no motorcycles). speedLimit -1 (none given).
- **Quirks.** No export quirks of real highD files are known (no BOM, CRLF, separators or
  duplicates reported); its conventions above are what its readers handle. With `--quirks` the
  records keep the simulation's frame gaps, as every format does, and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.sources.highd import schema as hs
from ngsim_graphs.sources.highd.recordings import FRAME_RATE_HZ
from ngsim_graphs.sources.highd.schema import HighdFile
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.cleaning import FEET_TO_M
from ngsim_graphs.sources.ngsim.recordings import PACIFIC_DAYLIGHT, Recording
from ngsim_graphs.synth.road import LANE_WIDTH_FT, ROADWAYS

DECIMALS = 3
TOP_M = 8.0  # image y of the upper carriageway's top marking
MEDIAN_M = 3.0  # between the two carriageways
IMAGE_MARGIN_M = 25.0  # along x, beyond each end of the section: more than any vehicle is long
LOCATION_IDS = {"us-101": 1, "i-80": 2}  # the highD locationId of each simulated section
UPPER, LOWER = 1, 2  # drivingDirection
_INTERPOLATED = (ns.LOCAL_X, ns.LOCAL_Y, ns.V_VEL, ns.V_ACC)


@dataclass(frozen=True)
class ImageLayout:
    """Where a simulated section lies in a highD image, metres (x right, y down)."""

    lanes: int
    section_m: float  # Local_Y range of the section
    upper_markings_m: tuple[float, ...]
    lower_markings_m: tuple[float, ...]

    @property
    def image_length_m(self) -> float:
        return self.section_m + 2 * IMAGE_MARGIN_M


def image_layout(location: str) -> ImageLayout:
    """The layout of a simulated location's section; markings rounded as they are written."""
    roadway = ROADWAYS[location]
    width_m = LANE_WIDTH_FT * FEET_TO_M
    upper = tuple(round(TOP_M + i * width_m, DECIMALS) for i in range(roadway.lanes + 1))
    lower = tuple(
        round(upper[-1] + MEDIAN_M + i * width_m, DECIMALS) for i in range(roadway.lanes + 1)
    )
    return ImageLayout(roadway.lanes, roadway.length_ft * FEET_TO_M, upper, lower)


def highd_paths(out_dir: Path, recordings: int) -> list[Path]:
    """The files of `recordings` highD recordings in out_dir: per recording, in HighdFile order."""
    return [
        out_dir / f"{number:02d}_{kind.value}.csv"
        for number in range(1, recordings + 1)
        for kind in HighdFile
    ]


def driving_direction(index: int) -> int:
    """The drivingDirection of synth's recording `index` (0-based): 2, 1, 2, 1, ..."""
    return LOWER if index % 2 == 0 else UPPER


def _metric(rows: pl.DataFrame) -> pl.DataFrame:
    """NGSIM rows (sorted by vehicle, frame) in metres, with the leader's speed (m/s, 0: none)."""
    feet = [
        pl.col(c) * FEET_TO_M
        for c in (ns.LOCAL_X, ns.LOCAL_Y, ns.V_VEL, ns.V_ACC, ns.V_LENGTH, ns.V_WIDTH)
    ]
    metric = rows.with_columns(*feet, (pl.col(ns.SPACE_HEADWAY) * FEET_TO_M).alias(hs.HIGHD_DHW))
    leader = metric.select(
        s.FRAME_ID, pl.col(s.VEHICLE_ID).alias(s.PRECEDING), pl.col(ns.V_VEL).alias("leader_v")
    )
    joined = metric.join(leader, on=[s.FRAME_ID, s.PRECEDING], how="left", maintain_order="left")
    return joined.with_columns(pl.col("leader_v").fill_null(0.0))


def _on_25_hz(rows: pl.DataFrame) -> pl.DataFrame:
    """One row per highD frame (column HIGHD_FRAME): frame f = 5 + 2.5 n shows NGSIM frame n;
    between consecutive NGSIM frames of a vehicle, linear interpolation of _INTERPOLATED."""
    n = pl.col(s.FRAME_ID)
    has_next = (pl.col(s.VEHICLE_ID).shift(-1) == pl.col(s.VEHICLE_ID)) & (n.shift(-1) == n + 1)
    even = n % 2 == 0
    first = pl.when(even).then(n * 5 // 2 + 5).otherwise((n * 5 + 1) // 2 + 5)  # ceil(2.5 n) + 5
    count = (
        pl.when(has_next.fill_null(False))
        .then(pl.when(even).then(3).otherwise(2))
        .otherwise(even.cast(pl.Int32))
    )
    nexts = [pl.col(c).shift(-1).alias(f"next_{c}") for c in _INTERPOLATED]
    spread = rows.with_columns(*nexts, first.alias("first"), pl.int_ranges(0, count).alias("j"))
    exploded = spread.explode("j").drop_nulls("j")
    frame = pl.col("first") + pl.col("j")
    weight = (2 * frame - 10 - 5 * n) / 5  # (f - 5) / 2.5 - n, exactly 0 on the grid
    between = [
        pl.when(weight == 0)
        .then(pl.col(c))
        .otherwise(pl.col(c) + weight * (pl.col(f"next_{c}") - pl.col(c)))
        for c in _INTERPOLATED
    ]
    return exploded.with_columns(frame.cast(pl.Int32).alias(hs.HIGHD_FRAME), *between)


def tracks_table(rows: pl.DataFrame, layout: ImageLayout, direction: int) -> pl.DataFrame:
    """The NN_tracks.csv table (HIGHD_TRACKS_HEADER) of one recording's NGSIM rows."""
    frames = _on_25_hz(_metric(rows.sort(s.VEHICLE_ID, s.FRAME_ID)))
    sign = 1.0 if direction == LOWER else -1.0
    length, width = pl.col(ns.V_LENGTH), pl.col(ns.V_WIDTH)
    if direction == LOWER:
        x = IMAGE_MARGIN_M + pl.col(ns.LOCAL_Y) - length
        y = layout.lower_markings_m[0] + pl.col(ns.LOCAL_X) - width / 2
        lane = layout.lanes + 2 + pl.col(s.LANE_ID)
    else:
        x = IMAGE_MARGIN_M + layout.section_m - pl.col(ns.LOCAL_Y)
        y = layout.upper_markings_m[-1] - pl.col(ns.LOCAL_X) - width / 2
        lane = layout.lanes + 2 - pl.col(s.LANE_ID)
    ahead = pl.col(s.PRECEDING) != ns.NO_NEIGHBOUR_ID
    closing = ahead & (pl.col(ns.V_VEL) > pl.col("leader_v"))
    timed = ahead & (pl.col(ns.TIME_HEADWAY) < ns.NO_LEADER_TIME_HEADWAY_S)
    zero = pl.lit(0.0)
    front_gap = layout.image_length_m - x - length
    table = frames.with_columns(
        x.alias(hs.HIGHD_X),
        y.alias(hs.HIGHD_Y),
        length.alias(hs.HIGHD_WIDTH),
        width.alias(hs.HIGHD_HEIGHT),
        (sign * pl.col(ns.V_VEL) + 0.0).alias(hs.HIGHD_X_VELOCITY),
        zero.alias(hs.HIGHD_Y_VELOCITY),
        (sign * pl.col(ns.V_ACC) + 0.0).alias(hs.HIGHD_X_ACCELERATION),
        zero.alias(hs.HIGHD_Y_ACCELERATION),
        (front_gap if direction == LOWER else x).alias("frontSightDistance"),
        (x if direction == LOWER else front_gap).alias("backSightDistance"),
        pl.when(ahead).then(pl.col(hs.HIGHD_DHW)).otherwise(zero).alias(hs.HIGHD_DHW),
        pl.when(timed).then(pl.col(ns.TIME_HEADWAY)).otherwise(zero).alias(hs.HIGHD_THW),
        pl.when(closing)
        .then(pl.col(hs.HIGHD_DHW) / (pl.col(ns.V_VEL) - pl.col("leader_v")))
        .otherwise(zero)
        .alias(hs.HIGHD_TTC),
        (sign * pl.col("leader_v") + 0.0).alias(hs.HIGHD_PRECEDING_X_VELOCITY),  # + 0.0: no -0.0
        pl.col(s.PRECEDING).alias(hs.HIGHD_PRECEDING_ID),
        pl.col(s.FOLLOWING).alias(hs.HIGHD_FOLLOWING_ID),
        lane.cast(pl.Int16).alias(hs.HIGHD_LANE_ID),
        pl.col(s.VEHICLE_ID).alias(hs.HIGHD_ID),
    )
    others = [pl.lit(0).alias(c) for c in hs.HIGHD_TRACKS_HEADER if c not in table.columns]
    return (
        table.with_columns(*others).select(hs.HIGHD_TRACKS_HEADER).sort(hs.HIGHD_ID, hs.HIGHD_FRAME)
    )


def _positive_min(column: str) -> pl.Expr:
    """The smallest positive value of a column, -1 where it has none (highD's way)."""
    return pl.col(column).filter(pl.col(column) > 0).min().fill_null(-1.0)


def tracks_meta_table(tracks: pl.DataFrame, rows: pl.DataFrame, direction: int) -> pl.DataFrame:
    """The NN_tracksMeta.csv table: one row per vehicle of `tracks` (its NN_tracks.csv table)."""
    classes = (
        rows.group_by(s.VEHICLE_ID)
        .agg(pl.col(s.V_CLASS).first())
        .rename({s.VEHICLE_ID: hs.HIGHD_ID})
    )
    speed = pl.col(hs.HIGHD_X_VELOCITY).abs()
    per_vehicle = tracks.group_by(hs.HIGHD_ID).agg(
        pl.col(hs.HIGHD_WIDTH).first(),
        pl.col(hs.HIGHD_HEIGHT).first(),
        pl.col(hs.HIGHD_FRAME).min().alias("initialFrame"),
        pl.col(hs.HIGHD_FRAME).max().alias("finalFrame"),
        pl.len().alias(hs.HIGHD_NUM_FRAMES),
        (pl.col(hs.HIGHD_X).last() - pl.col(hs.HIGHD_X).first()).abs().alias("traveledDistance"),
        speed.min().alias("minXVelocity"),
        speed.max().alias("maxXVelocity"),
        speed.mean().alias("meanXVelocity"),
        _positive_min(hs.HIGHD_DHW).alias("minDHW"),
        _positive_min(hs.HIGHD_THW).alias("minTHW"),
        _positive_min(hs.HIGHD_TTC).alias("minTTC"),
        (pl.col(hs.HIGHD_LANE_ID).diff() != 0).sum().alias("numLaneChanges"),
    )
    named = per_vehicle.join(classes, on=hs.HIGHD_ID).with_columns(
        pl.when(pl.col(s.V_CLASS) == 3)
        .then(pl.lit("Truck"))
        .otherwise(pl.lit("Car"))
        .alias(hs.HIGHD_CLASS),
        pl.lit(direction).alias(hs.HIGHD_DRIVING_DIRECTION),
    )
    return named.select(hs.HIGHD_TRACKS_META_HEADER).sort(hs.HIGHD_ID)


def _markings(values: tuple[float, ...]) -> str:
    return ";".join(f"{v:.{DECIMALS}f}" for v in values)


def recording_meta_table(
    recording: Recording, recording_id: int, meta: pl.DataFrame, layout: ImageLayout, minutes: float
) -> pl.DataFrame:
    """The NN_recordingMeta.csv table (one row) of a recording, from its tracksMeta table."""
    start = datetime.fromtimestamp(recording.start_epoch_ms / 1000, PACIFIC_DAYLIGHT)
    trucks = int((meta[hs.HIGHD_CLASS] == "Truck").sum())
    values = [
        recording_id,
        FRAME_RATE_HZ,
        LOCATION_IDS[recording.location],
        -1.0,
        f"{start:%m.%Y}",
        f"{start:%a}",
        f"{start:%H:%M}",
        float(minutes * 60),
        float(meta["traveledDistance"].sum()),
        float(meta[hs.HIGHD_NUM_FRAMES].sum()) / FRAME_RATE_HZ,
        meta.height,
        meta.height - trucks,
        trucks,
        _markings(layout.upper_markings_m),
        _markings(layout.lower_markings_m),
    ]
    return pl.DataFrame([values], schema=list(hs.HIGHD_RECORDING_META_HEADER), orient="row")


def highd_tables(
    rows: pl.DataFrame, recording: Recording, index: int, minutes: float
) -> dict[HighdFile, pl.DataFrame]:
    """The three tables of synth's recording `index` (0-based; highD id index + 1), from its rows."""
    layout = image_layout(recording.location)
    direction = driving_direction(index)
    tracks = tracks_table(rows, layout, direction)
    meta = tracks_meta_table(tracks, rows, direction)
    return {
        HighdFile.TRACKS: tracks,
        HighdFile.TRACKS_META: meta,
        HighdFile.RECORDING_META: recording_meta_table(recording, index + 1, meta, layout, minutes),
    }
