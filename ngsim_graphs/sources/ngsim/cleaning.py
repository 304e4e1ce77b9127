"""NGSIM's own cleaning of raw rows: which are complete, which of two conflicting duplicates
is kept, and the tracks table's SI units from NGSIM's feet (the rest is `sources.cleaning`)."""

from __future__ import annotations

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.sources.ngsim import schema as ns

FEET_TO_M = 0.3048

# Conflicting duplicates (one vehicle and frame, different values) keep the row that sorts first
# by these columns: a rule that depends on the values only, never on the order of the file.
CONFLICT_ORDER: tuple[str, ...] = (ns.LOCAL_Y, ns.LOCAL_X, ns.V_VEL, *ns.TXT_COLUMNS)


def is_complete() -> pl.Expr:
    """Rows with every required field (vehicle, frame, time, position, speed); others are dropped."""
    return pl.all_horizontal(pl.col(ns.REQUIRED_VALUE_COLUMNS).is_not_null())


def to_si_units(frame: pl.DataFrame) -> pl.DataFrame:
    """The tracks table's columns in SI units, from raw columns in feet, feet/s and ms.

    NGSIM's sentinels become null: Preceding/Following 0 (none) and Time_Headway 9999.99 (no
    leader); Space_Headway is null wherever there is no preceding vehicle.
    """
    feet = lambda column: pl.col(column) * FEET_TO_M  # noqa: E731
    no_leader = pl.col(s.PRECEDING).is_null() | (pl.col(s.PRECEDING) == ns.NO_NEIGHBOUR_ID)
    return frame.select(
        s.LOCATION,
        s.PERIOD,
        s.VEHICLE_ID,
        s.SEGMENT,
        s.FRAME_ID,
        (pl.col(s.FRAME_ID) * 0.1).alias(s.TIME_S),
        s.GLOBAL_TIME,
        feet(ns.LOCAL_X).alias(s.X_M),
        feet(ns.LOCAL_Y).alias(s.Y_M),
        feet(ns.V_VEL).alias(s.SPEED_MPS),
        feet(ns.V_ACC).alias(s.ACCEL_MPS2),
        s.LANE_ID,
        s.V_CLASS,
        feet(ns.V_LENGTH).alias(s.LENGTH_M),
        feet(ns.V_WIDTH).alias(s.WIDTH_M),
        pl.col(s.PRECEDING).replace(ns.NO_NEIGHBOUR_ID, None),
        pl.col(s.FOLLOWING).replace(ns.NO_NEIGHBOUR_ID, None),
        pl.when(no_leader).then(None).otherwise(feet(ns.SPACE_HEADWAY)).alias(s.SPACE_HEADWAY_M),
        pl.when(pl.col(ns.TIME_HEADWAY) >= ns.NO_LEADER_TIME_HEADWAY_S)
        .then(None)
        .otherwise(pl.col(ns.TIME_HEADWAY))
        .alias(s.TIME_HEADWAY_S),
    )
