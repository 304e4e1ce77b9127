"""highD's raw columns and dtypes (docs/highd.md), imported as `hs`. No logic lives here.

Every name as highD's header spells it; readers match them case-insensitively. Each recording NN
is three CSV files: NN_tracks.csv (one row per vehicle and 25 Hz frame), NN_tracksMeta.csv (one
row per vehicle), NN_recordingMeta.csv (one row). Units are highD's own: metres, m/s, m/s^2,
image coordinates (x right, y down).
"""

from __future__ import annotations

from enum import Enum
from typing import Final

import polars as pl


class HighdFile(str, Enum):
    """The three files of one highD recording: the name's suffix, `NN_<suffix>.csv`."""

    TRACKS = "tracks"
    TRACKS_META = "tracksMeta"
    RECORDING_META = "recordingMeta"


HIGHD_FRAME: Final = "frame"  # 25 Hz frame number, from 1
HIGHD_ID: Final = "id"  # track id in tracks/tracksMeta (>= 1); recording id in recordingMeta
HIGHD_X: Final = "x"  # upper-left corner of the bounding box, image x (right), m
HIGHD_Y: Final = "y"  # upper-left corner of the bounding box, image y (down), m
HIGHD_WIDTH: Final = "width"  # the bounding box along image x: the vehicle's length, m
HIGHD_HEIGHT: Final = "height"  # the bounding box along image y: the vehicle's width, m
HIGHD_X_VELOCITY: Final = "xVelocity"
HIGHD_Y_VELOCITY: Final = "yVelocity"
HIGHD_X_ACCELERATION: Final = "xAcceleration"
HIGHD_Y_ACCELERATION: Final = "yAcceleration"
HIGHD_DHW: Final = "dhw"  # distance headway, m; 0: no preceding vehicle
HIGHD_THW: Final = "thw"  # time headway, s; 0: no preceding vehicle
HIGHD_TTC: Final = "ttc"  # time to collision, s; 0: none
HIGHD_PRECEDING_X_VELOCITY: Final = "precedingXVelocity"
HIGHD_PRECEDING_ID: Final = "precedingId"  # 0: none
HIGHD_FOLLOWING_ID: Final = "followingId"  # 0: none
HIGHD_LANE_ID: Final = "laneId"  # numbered from the top of the image, edges and median included
# The neighbours on either side: not in the tracks table, but parsed, so that a column of other
# values in their place (accelerations, not whole) is refused.
HIGHD_SIDE_IDS: Final[tuple[str, ...]] = (
    "leftPrecedingId",
    "leftAlongsideId",
    "leftFollowingId",
    "rightPrecedingId",
    "rightAlongsideId",
    "rightFollowingId",
)

HIGHD_TRACKS_HEADER: Final[tuple[str, ...]] = (
    HIGHD_FRAME,
    HIGHD_ID,
    HIGHD_X,
    HIGHD_Y,
    HIGHD_WIDTH,
    HIGHD_HEIGHT,
    HIGHD_X_VELOCITY,
    HIGHD_Y_VELOCITY,
    HIGHD_X_ACCELERATION,
    HIGHD_Y_ACCELERATION,
    "frontSightDistance",
    "backSightDistance",
    HIGHD_DHW,
    HIGHD_THW,
    HIGHD_TTC,
    HIGHD_PRECEDING_X_VELOCITY,
    HIGHD_PRECEDING_ID,
    HIGHD_FOLLOWING_ID,
    *HIGHD_SIDE_IDS,
    HIGHD_LANE_ID,
)
# The tracks columns the reader parses, with their dtypes; the rest of the header is not read.
HIGHD_TRACKS_SCHEMA: Final = pl.Schema(
    {
        HIGHD_FRAME: pl.Int32,
        HIGHD_ID: pl.Int32,
        HIGHD_X: pl.Float64,
        HIGHD_Y: pl.Float64,
        HIGHD_WIDTH: pl.Float64,
        HIGHD_HEIGHT: pl.Float64,
        HIGHD_X_VELOCITY: pl.Float64,
        HIGHD_Y_VELOCITY: pl.Float64,
        HIGHD_X_ACCELERATION: pl.Float64,
        HIGHD_Y_ACCELERATION: pl.Float64,
        HIGHD_DHW: pl.Float64,
        HIGHD_THW: pl.Float64,
        HIGHD_PRECEDING_ID: pl.Int32,
        HIGHD_FOLLOWING_ID: pl.Int32,
        **dict.fromkeys(HIGHD_SIDE_IDS, pl.Int32),
        HIGHD_LANE_ID: pl.Int16,
    }
)
# A tracks row with one of these empty is dropped and counted (rows_missing_values).
HIGHD_REQUIRED_COLUMNS: Final[tuple[str, ...]] = (
    HIGHD_FRAME,
    HIGHD_ID,
    HIGHD_X,
    HIGHD_Y,
    HIGHD_WIDTH,
    HIGHD_HEIGHT,
    HIGHD_X_VELOCITY,
)

HIGHD_CLASS: Final = "class"  # "Car" or "Truck"
HIGHD_DRIVING_DIRECTION: Final = "drivingDirection"  # 1: upper lanes, towards -x; 2: lower, +x
HIGHD_NUM_FRAMES: Final = "numFrames"  # rows of the track in the tracks file
HIGHD_TRACKS_META_HEADER: Final[tuple[str, ...]] = (
    HIGHD_ID,
    HIGHD_WIDTH,
    HIGHD_HEIGHT,
    "initialFrame",
    "finalFrame",
    HIGHD_NUM_FRAMES,
    HIGHD_CLASS,
    HIGHD_DRIVING_DIRECTION,
    "traveledDistance",
    "minXVelocity",
    "maxXVelocity",
    "meanXVelocity",
    "minDHW",
    "minTHW",
    "minTTC",
    "numLaneChanges",
)
HIGHD_TRACKS_META_SCHEMA: Final = pl.Schema(
    {
        HIGHD_ID: pl.Int32,
        HIGHD_NUM_FRAMES: pl.Int32,
        HIGHD_CLASS: pl.String,
        HIGHD_DRIVING_DIRECTION: pl.Int8,
    }
)
# highD's vehicle classes as NGSIM's v_class codes (matched case-insensitively).
HIGHD_CLASS_CODES: Final[dict[str, int]] = {"car": 2, "truck": 3}

HIGHD_FRAME_RATE: Final = "frameRate"  # 25
HIGHD_LOCATION_ID: Final = "locationId"
HIGHD_UPPER_LANE_MARKINGS: Final = "upperLaneMarkings"  # image y of the markings, "a;b;c", m
HIGHD_LOWER_LANE_MARKINGS: Final = "lowerLaneMarkings"
HIGHD_RECORDING_META_HEADER: Final[tuple[str, ...]] = (
    HIGHD_ID,
    HIGHD_FRAME_RATE,
    HIGHD_LOCATION_ID,
    "speedLimit",
    "month",
    "weekDay",
    "startTime",
    "duration",
    "totalDrivenDistance",
    "totalDrivenTime",
    "numVehicles",
    "numCars",
    "numTrucks",
    HIGHD_UPPER_LANE_MARKINGS,
    HIGHD_LOWER_LANE_MARKINGS,
)
HIGHD_RECORDING_META_SCHEMA: Final = pl.Schema(
    {
        HIGHD_ID: pl.Int32,
        HIGHD_FRAME_RATE: pl.Int32,
        HIGHD_LOCATION_ID: pl.Int32,
        HIGHD_UPPER_LANE_MARKINGS: pl.String,
        HIGHD_LOWER_LANE_MARKINGS: pl.String,
    }
)
HIGHD_NO_NEIGHBOUR: Final = 0  # precedingId/followingId, dhw/thw/ttc: none
