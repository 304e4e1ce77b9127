"""highD's image coordinates to the tracks table's road frame, per driving direction; its row
limits (`LIMITS`, the highD Source's).

highD's (x, y) is the upper-left corner of a vehicle's bounding box in image coordinates: x to
the right along the road, y downwards, metres. The box is `width` along x (the vehicle's length)
and `height` along y (its width). drivingDirection 1 is the upper lanes, driving towards -x;
2 the lower lanes, towards +x. Traffic keeps right, so the median lies on each direction's left:
below the upper lanes, above the lower ones.

Our point is the vehicle's front centre; `y_m` grows along its travel and `x_m` to the driver's
right, measured from the carriageway's left (median-side) edge marking, as NGSIM's Local_X is
from the left edge of the road:

| drivingDirection     | y_m (front)          | x_m (centre)                              |
| -------------------- | -------------------- | ----------------------------------------- |
| 2: lower lanes, +x   | x + width            | (y + height / 2) - lowerLaneMarkings[0]   |
| 1: upper lanes, -x   | UPPER_ORIGIN_M - x   | upperLaneMarkings[-1] - (y + height / 2)  |

A lane change to the left (towards the median) lowers `x_m`, and gives a negative heading, in
both directions. The two directions share a recording but, in a frame where both move along +y,
not a road: direction 1's y runs backwards from UPPER_ORIGIN_M = 2,000 m, so with highD's ~420 m
images its vehicles (y about 1,580..2,000 m) stay over a kilometre from direction 2's (y about
0..450 m) and never share a graph (d_sense is 50 m).

speed = |(xVelocity, yVelocity)|; acceleration along travel = xAcceleration, its sign flipped for
direction 1. Sentinels become null: precedingId/followingId 0 (none), dhw/thw 0 (no leader).

Every column that reaches the tracks table has a row check (`row_drop_reason`): frame, id,
position, speed, acceleration, the vehicle's size, laneId, the headways and neighbour ids; and a
vehicle whose front moves against its driving direction loses its rows (`moves_backwards`).
"""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.schema import DropReason
from ngsim_graphs.sources.highd import schema as hs
from ngsim_graphs.sources.highd.files import RecordingMeta
from ngsim_graphs.sources.highd.recordings import FRAME_RATE_HZ
from ngsim_graphs.sources.limits import PhysicalLimits

# What a highD row may hold (the highD Source's `limits`): the metric defaults, and frame numbers
# up to two hours of its 25 Hz frames.
LIMITS = PhysicalLimits(max_frame_id=2 * 3_600 * FRAME_RATE_HZ)
UPPER_ORIGIN_M = 2_000.0  # direction 1: y_m = UPPER_ORIGIN_M - image x of the front
UPPER, LOWER = 1, 2  # drivingDirection
# thw's bound: 2.8 hours, NGSIM's (its "no leader" value); at a standstill thw = dhw / speed is
# large but finite.
MAX_TIME_HEADWAY_S = 9_999.99
# A vehicle whose front ends its record this far behind where it began drives against its
# drivingDirection (highD's tracker jitters by centimetres; no one reverses on a motorway).
MAX_BACKWARDS_M = 1.0

# The columns a tracks file gives its recording, in the tracks table's units and names.
STAGED_SCHEMA = pl.Schema(
    {
        s.VEHICLE_ID: pl.Int32,
        s.FRAME_ID: pl.Int32,
        s.X_M: pl.Float64,
        s.Y_M: pl.Float64,
        s.SPEED_MPS: pl.Float64,
        s.ACCEL_MPS2: pl.Float64,
        s.LANE_ID: pl.Int16,
        s.V_CLASS: pl.Int8,
        s.LENGTH_M: pl.Float64,
        s.WIDTH_M: pl.Float64,
        s.PRECEDING: pl.Int32,
        s.FOLLOWING: pl.Int32,
        s.SPACE_HEADWAY_M: pl.Float64,
        s.TIME_HEADWAY_S: pl.Float64,
    }
)


def _norm(x: str, y: str) -> pl.Expr:
    """|(x, y)| of two columns; an empty y counts as 0."""
    return (pl.col(x).pow(2) + pl.col(y).fill_null(0.0).pow(2)).sqrt()


def _bad_headway(limits: PhysicalLimits) -> pl.Expr:
    """dhw (m) or thw (s) out of range, a neighbour id below 0, or a headway without a leader:
    highD writes dhw = thw = 0 where precedingId is 0 (none)."""
    no_leader = pl.col(hs.HIGHD_PRECEDING_ID) == hs.HIGHD_NO_NEIGHBOUR
    headway = (pl.col(hs.HIGHD_DHW) != 0) | (pl.col(hs.HIGHD_THW) != 0)
    return (
        ~pl.col(hs.HIGHD_DHW).is_between(0, limits.max_abs_position_m)
        | ~pl.col(hs.HIGHD_THW).is_between(0, MAX_TIME_HEADWAY_S)
        | (pl.col(hs.HIGHD_PRECEDING_ID) < 0)
        | (pl.col(hs.HIGHD_FOLLOWING_ID) < 0)
        | (no_leader & headway)
    )


def _checks(limits: PhysicalLimits) -> tuple[tuple[DropReason, pl.Expr], ...]:
    """(reason, True where a raw tracks row breaks its limit), in the order they are tried."""
    far = limits.max_abs_position_m
    frame = pl.col(hs.HIGHD_FRAME)
    return (
        (DropReason.FRAME_ID, (frame < 0) | (frame > limits.max_frame_id)),
        (DropReason.VEHICLE_ID, pl.col(hs.HIGHD_ID) < 1),
        (DropReason.POSITION, (pl.col(hs.HIGHD_X).abs() > far) | (pl.col(hs.HIGHD_Y).abs() > far)),
        (DropReason.SPEED, _norm(hs.HIGHD_X_VELOCITY, hs.HIGHD_Y_VELOCITY) > limits.max_speed_mps),
        (
            DropReason.ACCELERATION,
            _norm(hs.HIGHD_X_ACCELERATION, hs.HIGHD_Y_ACCELERATION) > limits.max_abs_accel_mps2,
        ),
        (
            DropReason.VEHICLE_SIZE,  # the box's width is the vehicle's length, height its width
            ~pl.col(hs.HIGHD_WIDTH).is_between(0, limits.max_vehicle_length_m, closed="right")
            | ~pl.col(hs.HIGHD_HEIGHT).is_between(0, limits.max_vehicle_width_m, closed="right"),
        ),
        (DropReason.LANE, ~pl.col(hs.HIGHD_LANE_ID).is_between(0, limits.max_lane_id)),
        (DropReason.HEADWAY, _bad_headway(limits)),
    )


def row_drop_reason(limits: PhysicalLimits) -> pl.Expr:
    """The first DropReason value a raw tracks row breaks (null values break nothing); null for
    a good row. `limits` are highD's (`LIMITS`) or others a build was given: metric, the frame
    limit in its 25 Hz frames."""
    checks = _checks(limits)
    reason, failed = checks[0]
    chain = pl.when(failed.fill_null(False)).then(pl.lit(reason.value))
    for reason, failed in checks[1:]:
        chain = chain.when(failed.fill_null(False)).then(pl.lit(reason.value))
    return chain.otherwise(pl.lit(None, dtype=pl.String))


def moves_backwards() -> pl.Expr:
    """True for every row of a vehicle whose front (`Y_M`, along its drivingDirection) is more
    than MAX_BACKWARDS_M behind at its last frame than at its first: a vehicle put on the other
    carriageway by a wrong drivingDirection. Over road-frame rows (`to_road_frame`)."""
    front = pl.col(s.Y_M).sort_by(s.FRAME_ID)
    return (front.last() - front.first() < -MAX_BACKWARDS_M).over(s.VEHICLE_ID)


def _none_if_zero(column: str) -> pl.Expr:
    return pl.when(pl.col(column) != hs.HIGHD_NO_NEIGHBOUR).then(pl.col(column))


def to_road_frame(rows: pl.DataFrame, meta: RecordingMeta) -> pl.DataFrame:
    """STAGED_SCHEMA columns (plus any provenance columns) of raw tracks rows.

    `rows` hold HIGHD_TRACKS_SCHEMA columns and, per row, its vehicle's V_CLASS and
    HIGHD_DRIVING_DIRECTION (from the tracksMeta file).
    """
    upper = pl.col(hs.HIGHD_DRIVING_DIRECTION) == UPPER
    centre_y = pl.col(hs.HIGHD_Y) + pl.col(hs.HIGHD_HEIGHT) / 2
    x_m = (
        pl.when(upper)
        .then(meta.upper_markings_m[-1] - centre_y)
        .otherwise(centre_y - meta.lower_markings_m[0])
    )
    y_m = (
        pl.when(upper)
        .then(UPPER_ORIGIN_M - pl.col(hs.HIGHD_X))
        .otherwise(pl.col(hs.HIGHD_X) + pl.col(hs.HIGHD_WIDTH))
    )
    along = pl.when(upper).then(-1.0).otherwise(1.0)
    no_leader = (
        pl.col(hs.HIGHD_PRECEDING_ID).fill_null(hs.HIGHD_NO_NEIGHBOUR) == hs.HIGHD_NO_NEIGHBOUR
    )
    provenance = [c for c in rows.columns if c in s.PROVENANCE_SCHEMA]
    staged = rows.select(
        pl.col(hs.HIGHD_ID).alias(s.VEHICLE_ID),
        pl.col(hs.HIGHD_FRAME).alias(s.FRAME_ID),
        x_m.alias(s.X_M),
        y_m.alias(s.Y_M),
        _norm(hs.HIGHD_X_VELOCITY, hs.HIGHD_Y_VELOCITY).alias(s.SPEED_MPS),
        (along * pl.col(hs.HIGHD_X_ACCELERATION) + 0.0).alias(s.ACCEL_MPS2),  # + 0.0: no -0.0
        pl.col(hs.HIGHD_LANE_ID).alias(s.LANE_ID),
        s.V_CLASS,
        pl.col(hs.HIGHD_WIDTH).alias(s.LENGTH_M),
        pl.col(hs.HIGHD_HEIGHT).alias(s.WIDTH_M),
        _none_if_zero(hs.HIGHD_PRECEDING_ID).alias(s.PRECEDING),
        _none_if_zero(hs.HIGHD_FOLLOWING_ID).alias(s.FOLLOWING),
        pl.when(no_leader)
        .then(None)
        .otherwise(_none_if_zero(hs.HIGHD_DHW))
        .alias(s.SPACE_HEADWAY_M),
        _none_if_zero(hs.HIGHD_THW).alias(s.TIME_HEADWAY_S),
        *provenance,
    )
    return staged.cast(dict(STAGED_SCHEMA))
