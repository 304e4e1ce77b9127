"""Column names and dtypes of every table the pipeline writes, and of the sources' common rows.
No logic lives here.

Each source's raw columns live in its folder (`sources/ngsim/schema.py`,
`sources/highd/schema.py`); the tracks table and everything after it is in SI units (metres,
seconds, metres per second, radians).
"""

from __future__ import annotations

from enum import Enum
from typing import Final

import polars as pl


class RawFormat(str, Enum):
    """The file formats of raw trajectories: NGSIM's three (docs/conventions.md), which the NGSIM
    reader tells apart, and highD's (docs/highd.md), which only the highD source reads."""

    PORTAL = "portal"  # combined CSV of all locations, with a Location column
    CSV = "csv"  # one period, CSV with a header
    TXT = "txt"  # one period, whitespace-separated, no header
    HIGHD = "highd"  # highD: NN_tracks.csv, NN_tracksMeta.csv, NN_recordingMeta.csv per recording


class SplitMode(str, Enum):
    """How ego windows are divided into train, validation and test (docs/conventions.md)."""

    VEHICLE = "vehicle"  # by Vehicle_ID within each recording (CS-LSTM's convention)
    TIME = "time"  # contiguous blocks of present time per recording, one window apart
    RANDOM = "random"  # seeded, by ego track


class Protocol(str, Enum):
    """Which samples a build makes (docs/conventions.md, "Samples" and "The cs-lstm protocol")."""

    AIGEM = "aigem"  # ego windows cut at a stride, the actors around the ego as targets
    CS_LSTM = "cs-lstm"  # CS-LSTM's kept rows on the grid, the row's vehicle the only target


class DropReason(str, Enum):
    """Why a raw row was dropped one by one (docs/trust.md): the reasons any source's rows may
    give; counted per reason in the manifest. A reason peculiar to one dataset is its source's
    (`Source.drop_reasons`: NGSIM's Global_Time and v_Class), counted beside these.

    Rows with an empty required field are counted apart (`rows_missing_values`): empty fields
    are a known quirk of real exports, these are not.
    """

    FRAME_ID = "frame_id_out_of_range"  # Frame_ID below 0 or above the limit
    VEHICLE_ID = "vehicle_id_out_of_range"  # Vehicle_ID below 1 (0 means "none" in NGSIM)
    POSITION = "position_out_of_range"  # |Local_X| or |Local_Y| beyond the limit
    SPEED = "speed_out_of_range"  # v_Vel below 0 or above the limit
    ACCELERATION = "acceleration_out_of_range"  # |v_Acc| above the limit
    POSITION_OUTLIER = "position_outlier"  # farther than the jump limit from both its neighbours
    VEHICLE_SIZE = "vehicle_size_out_of_range"  # length or width not above 0 or above the limit
    LANE = "lane_id_out_of_range"  # Lane_ID below 0 or above the limit
    HEADWAY = (
        "headway_out_of_range"  # a headway below 0 or beyond its limit, a neighbour id below 0
    )
    DIRECTION = "driving_against_direction"  # highD: moving against its drivingDirection


class Split(str, Enum):
    TRAIN = "train"
    VAL = "val"
    TEST = "test"


# The columns the tracks table shares with NGSIM's raw rows, named as NGSIM's header is in lower
# case (each source's raw columns are in its folder: `sources/ngsim/schema.py`, ...).
VEHICLE_ID: Final = "vehicle_id"
FRAME_ID: Final = "frame_id"
GLOBAL_TIME: Final = "global_time"
V_CLASS: Final = "v_class"
LANE_ID: Final = "lane_id"
PRECEDING: Final = "preceding"
FOLLOWING: Final = "following"
LOCATION: Final = "location"


# Where a raw row came from, carried until cleaning so that drops can name the file and line.
SOURCE_FILE: Final = "__source_file"  # index of the input file in the build's list of inputs
SOURCE_LINE: Final = "__source_line"  # 1-based line number in that file
PROVENANCE_SCHEMA: Final = pl.Schema({SOURCE_FILE: pl.UInt16, SOURCE_LINE: pl.Int64})

# Recording identity columns, added by the reader to every raw row.
PERIOD: Final = "period"
RECORDING_KEY: Final[tuple[str, str]] = (LOCATION, PERIOD)
RECORDING_INDEX: Final = "recording_index"  # a recording's index in its file, then in the build

# The tracks table: one row per track and 0.2 s grid step, SI units.
TRACK_ID = "track_id"  # dense id over the whole table, in (location, period, vehicle, frame) order
SEGMENT = "segment"  # 0, 1, ... : pieces of one vehicle's record split at frame gaps
TIME_S = "time_s"  # frame_id * 0.1 s: seconds since the recording's frame 0
X_M = "x_m"  # Local_X in metres (lateral)
Y_M = "y_m"  # Local_Y in metres (longitudinal, direction of travel)
HEADING_RAD = "heading_rad"  # from +y towards +x
SPEED_MPS = "speed_mps"
ACCEL_MPS2 = "accel_mps2"
LENGTH_M = "length_m"
WIDTH_M = "width_m"
SPACE_HEADWAY_M = "space_headway_m"
TIME_HEADWAY_S = "time_headway_s"

TRACKS_SCHEMA: Final = pl.Schema(
    {
        LOCATION: pl.String,
        PERIOD: pl.String,
        VEHICLE_ID: pl.Int32,
        SEGMENT: pl.Int16,
        TRACK_ID: pl.Int32,
        FRAME_ID: pl.Int32,
        TIME_S: pl.Float64,
        GLOBAL_TIME: pl.Int64,
        X_M: pl.Float64,
        Y_M: pl.Float64,
        HEADING_RAD: pl.Float64,
        SPEED_MPS: pl.Float64,
        ACCEL_MPS2: pl.Float64,
        LANE_ID: pl.Int16,
        V_CLASS: pl.Int8,
        LENGTH_M: pl.Float64,
        WIDTH_M: pl.Float64,
        PRECEDING: pl.Int32,  # null where NGSIM says 0 (none)
        FOLLOWING: pl.Int32,  # null where NGSIM says 0 (none)
        SPACE_HEADWAY_M: pl.Float64,  # null where there is no leader
        TIME_HEADWAY_S: pl.Float64,  # null where NGSIM says 9999.99 (no leader)
    }
)

# Grid nodes of a recording: the tracks table reduced to what graphs need, sorted by (step, track).
STEP = "step"  # grid step index: time_s / time_step_s
GRID_NODE_SCHEMA: Final = pl.Schema(
    {
        STEP: pl.Int32,
        TRACK_ID: pl.Int32,
        VEHICLE_ID: pl.Int32,
        X_M: pl.Float64,
        Y_M: pl.Float64,
        HEADING_RAD: pl.Float64,
        SPEED_MPS: pl.Float64,
    }
)

# Proximity edges of a recording as a table (`grid.pair_table`, `OpenBuild.proximity`),
# once per grid step: every pair of vehicles at most d_min apart, lower track id first. A
# sample's actor-actor edges are the pairs among its nodes. The build stores them as arrays.
TRACK_A = "track_a"
TRACK_B = "track_b"
DISTANCE_M = "distance_m"
PROXIMITY_SCHEMA: Final = pl.Schema(
    {STEP: pl.Int32, TRACK_A: pl.Int32, TRACK_B: pl.Int32, DISTANCE_M: pl.Float64}
)

# Samples of one split: one ego window each, with the counts of its graph.
SAMPLE_ID = "sample_id"  # 0.. within the split, in (location, period, ego track, start) order
EGO_TRACK_ID = "ego_track_id"
EGO_VEHICLE_ID = "ego_vehicle_id"
START_STEP = "start_step"  # the window's first history step
PRESENT_STEP = "present_step"  # start_step + history_steps - 1
ORIGIN_X_M = "origin_x_m"  # the ego's position at the present step: (0, 0) of the sample frame
ORIGIN_Y_M = "origin_y_m"
SAMPLE_SCHEMA: Final = pl.Schema(
    {
        SAMPLE_ID: pl.Int32,
        LOCATION: pl.String,
        PERIOD: pl.String,
        EGO_TRACK_ID: pl.Int32,
        EGO_VEHICLE_ID: pl.Int32,
        START_STEP: pl.Int32,
        PRESENT_STEP: pl.Int32,
        ORIGIN_X_M: pl.Float64,
        ORIGIN_Y_M: pl.Float64,
    }
)
# The explicit graph tables of `ngsim-graphs export` (sample-local node indices).
NODE: Final = "node"  # sample-local node index
K: Final = "k"  # history step of a node, 0..K_H-1 (K_H-1: the present)
IS_EGO: Final = "is_ego"
EDGE_SOURCE: Final = "source"  # sample-local node index an edge leaves
EDGE_DESTINATION: Final = "destination"  # sample-local node index an edge enters
DT_S: Final = "dt_s"  # a temporal edge's attribute, the time step
FUTURE_STEP: Final = "future_step"  # 0..K_F-1: 0.2 s .. 5 s after the present
RECORDED: Final = "recorded"  # whether the target vehicle is recorded at that future step

SPLIT: Final = "split"  # the split of an ego window, while a build assigns them
N_NODES: Final = "n_nodes"
N_TARGETS: Final = "n_targets"
N_FULL_TARGETS: Final = "n_targets_full_future"  # targets recorded at every future step
# A split's samples table: SAMPLE_SCHEMA and the counts of their graphs, Int32 each: nodes, one
# column per edge type of the build (`edges.count_columns`: `n_spatial_edges`, ...), targets.
COUNT_DTYPE: Final = pl.Int32
