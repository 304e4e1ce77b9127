"""NGSIM's raw columns and dtypes (docs/conventions.md), imported as `ns`. No logic lives here.

Raw rows keep NGSIM's own units (feet, feet/s, feet/s^2, milliseconds). Readers match headers
case-insensitively, so `v_Length` and `v_length` both map to `v_length`; the columns the tracks
table keeps under NGSIM's names (vehicle_id, frame_id, ...) are the main schema's (`s`).
"""

from __future__ import annotations

from typing import Final

import polars as pl

from ngsim_graphs.schema import (
    FOLLOWING,
    FRAME_ID,
    GLOBAL_TIME,
    LANE_ID,
    PRECEDING,
    V_CLASS,
    VEHICLE_ID,
)

TOTAL_FRAMES: Final = "total_frames"
LOCAL_X: Final = "local_x"
LOCAL_Y: Final = "local_y"
GLOBAL_X: Final = "global_x"
GLOBAL_Y: Final = "global_y"
V_LENGTH: Final = "v_length"
V_WIDTH: Final = "v_width"
V_VEL: Final = "v_vel"
V_ACC: Final = "v_acc"
SPACE_HEADWAY: Final = "space_headway"
TIME_HEADWAY: Final = "time_headway"

# The 18 columns of the original whitespace text files, in file order. Per-period CSVs and the
# portal CSV carry them too (plus zone/intersection columns the pipeline does not use).
TXT_COLUMNS: Final[tuple[str, ...]] = (
    VEHICLE_ID,
    FRAME_ID,
    TOTAL_FRAMES,
    GLOBAL_TIME,
    LOCAL_X,
    LOCAL_Y,
    GLOBAL_X,
    GLOBAL_Y,
    V_LENGTH,
    V_WIDTH,
    V_CLASS,
    V_VEL,
    V_ACC,
    LANE_ID,
    PRECEDING,
    FOLLOWING,
    SPACE_HEADWAY,
    TIME_HEADWAY,
)

# The 25 columns of the combined portal CSV, in file order, with the official header spelling.
PORTAL_HEADER: Final[tuple[str, ...]] = (
    "Vehicle_ID",
    "Frame_ID",
    "Total_Frames",
    "Global_Time",
    "Local_X",
    "Local_Y",
    "Global_X",
    "Global_Y",
    "v_length",
    "v_Width",
    "v_Class",
    "v_Vel",
    "v_Acc",
    "Lane_ID",
    "O_Zone",
    "D_Zone",
    "Int_ID",
    "Section_ID",
    "Direction",
    "Movement",
    "Preceding",
    "Following",
    "Space_Headway",
    "Time_Headway",
    "Location",
)

# The header of a per-period CSV: the portal's columns without Location.
PERIOD_CSV_HEADER: Final[tuple[str, ...]] = PORTAL_HEADER[:-1]

# Dtypes of the parsed raw table (NGSIM units). Columns a reader needs before it can place a row
# anywhere; a row with one of them empty is dropped and counted.
RAW_SCHEMA: Final = pl.Schema(
    {
        VEHICLE_ID: pl.Int32,
        FRAME_ID: pl.Int32,
        TOTAL_FRAMES: pl.Int32,
        GLOBAL_TIME: pl.Int64,
        LOCAL_X: pl.Float64,
        LOCAL_Y: pl.Float64,
        GLOBAL_X: pl.Float64,
        GLOBAL_Y: pl.Float64,
        V_LENGTH: pl.Float64,
        V_WIDTH: pl.Float64,
        V_CLASS: pl.Int8,
        V_VEL: pl.Float64,
        V_ACC: pl.Float64,
        LANE_ID: pl.Int16,
        PRECEDING: pl.Int32,
        FOLLOWING: pl.Int32,
        SPACE_HEADWAY: pl.Float64,
        TIME_HEADWAY: pl.Float64,
    }
)
REQUIRED_VALUE_COLUMNS: Final[tuple[str, ...]] = (
    VEHICLE_ID,
    FRAME_ID,
    GLOBAL_TIME,
    LOCAL_X,
    LOCAL_Y,
    V_VEL,
)


# NGSIM sentinels.
NO_LEADER_TIME_HEADWAY_S: Final = 9999.99
NO_NEIGHBOUR_ID: Final = 0
