"""The tracks table contract: what every data source gives the pipeline, and how.

A source turns its dataset's files into one tracks table per recording (`schema.TRACKS_SCHEMA`,
one row per track and grid step). Everything after the seam (grid nodes, windows, splits, graphs,
scaling, the build directory) reads that table alone and knows no dataset. The contract:

- **Recording**: one continuous observation of one road section, on one clock. Its key is
  (`location`, `period`), two non-empty strings that make a file-system-safe name together.
  NGSIM: ("us-101", "0750am-0805am"); highD: ("highd-2", "01"), its locationId and recording id.
- **Vehicle and track**: `vehicle_id` >= 1 is the source's id, unique within the recording. A
  vehicle's record is split where frames are missing (`segment` 0, 1, ...); `track_id` numbers
  the tracks densely over the whole build in (recording, vehicle, segment) order. Nothing
  interpolates across a gap.
- **Time**: `time_s` is seconds since the recording's frame 0, and every row lies on the grid:
  `time_s / time_step_s` is an integer (up to float rounding). The source resamples by frame
  number, never by row position. `frame_id` is the source's own frame number (NGSIM 10 Hz, highD
  25 Hz) and `global_time` milliseconds on the source's clock (NGSIM: since the epoch; highD:
  since the recording's start): both are provenance only.
- **Space**: metres, in the road's frame. `y_m` grows along the direction of travel, `x_m` is
  lateral (NGSIM's Local_X: from the left edge of the road; highD: to the right of travel). The
  point is the front centre of the vehicle. `heading_rad` is measured from +y towards +x
  (`kinematics.add_heading`), `speed_mps` >= 0 is along the track, `accel_mps2` along it too.
- **Attributes**: `lane_id` is the source's lane number; `v_class` is NGSIM's code (1 motorcycle,
  2 car, 3 truck); `length_m`, `width_m`; `preceding` / `following` are vehicle ids or null;
  `space_headway_m` / `time_headway_s` are null where there is no leader.
- **Order**: rows sorted by (track_id, time_s), columns and dtypes exactly TRACKS_SCHEMA.

A source also reports what it read and dropped (`FileReport` per input file, `RecordingReport`
per recording): every dropped row is counted per reason, with the first line it was on. What a
raw row may hold is the source's to say (`Source.limits`, `sources.limits.PhysicalLimits`), not
the build config's; a build may be given others, and its manifest records those applied.

A recording is cleaned a part of its vehicles at a time (`TracksPart`: all the rows of each of
its vehicles), so a source's cleaning may look at one vehicle's rows only at a time; what it
judges over a whole recording (NGSIM: the median speed error) it takes from the parts' evidence.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.kinematics import add_heading
from ngsim_graphs.sources.limits import PhysicalLimits

RecordingKey = tuple[str, str]  # (location, period)


@dataclass(frozen=True)
class FileReport:
    """What reading one input file found, and which of its rows were dropped before cleaning.

    rows_read = rows_other_locations + rows_missing_values + sum(rows_dropped) + the rows it
    gave its chosen recordings (RecordingReport.rows).
    """

    path: str
    raw_format: str
    size_bytes: int
    sha256: str
    rows_read: int
    rows_other_locations: int  # of locations (or recordings) the build did not choose
    rows_missing_values: int  # an empty required field
    first_missing_line: int | None  # the first line with an empty required field
    rows_dropped: dict[str, int]  # per reason (shared, then its source's own): every reason
    first_dropped_line: dict[str, int]  # per reason with dropped rows: the first line
    rows_checked: int  # rows of the chosen recordings with every required field, kept or dropped
    locations_found: tuple[str, ...]  # every location the file holds, chosen or not
    recordings: tuple[str, ...]  # "location/period" of each chosen recording the file holds
    notes: tuple[str, ...] = ()  # what a user should know of how its rows were placed


@dataclass(frozen=True)
class RecordingReport:
    """What cleaning one recording counted, and the size of its tracks table."""

    location: str
    period: str
    rows: int  # rows of the recording that passed the row checks (duplicates included)
    exact_duplicates: int
    conflicting_duplicates: int
    position_outliers: int  # rows dropped: displaced from the neighbouring frames
    position_jumps: int  # other moves beyond the jump limit, each of which split a track
    gaps: int  # frame gaps, each of which split a vehicle's record into two tracks
    vehicles: int
    tracks: int
    grid_rows: int  # rows of the tracks table (the grid)
    # the speed column against the motion the positions show
    speed_mismatch_mps: float = math.nan  # median |speed column - shown speed|
    shown_speed_mps: float = math.nan  # median shown speed
    speed_rows_compared: int = 0
    first_outlier: tuple[int, int] | None = None  # (input file index, line) of the first outlier


@dataclass(frozen=True)
class FileRows:
    """One input file, read: its rows, which recording each belongs to, and its report.

    `rows` carry a RECORDING_INDEX column (null for rows no chosen recording keeps) and the
    provenance columns SOURCE_FILE and SOURCE_LINE; `recordings` maps each chosen recording's
    key to its index. The rows are lazy (in memory or scanned from the source's scratch files):
    they are taken a batch or a recording at a time.
    """

    rows: pl.LazyFrame
    recordings: dict[RecordingKey, int]
    report: FileReport

    def recording_rows(self, key: RecordingKey, where: pl.Expr | None = None) -> pl.LazyFrame:
        """The rows of one recording (those of them `where` holds), without RECORDING_INDEX;
        lazy, so that only what is collected of them is copied."""
        kept = pl.col(s.RECORDING_INDEX) == self.recordings[key]
        if where is not None:
            kept &= where
        return self.rows.filter(kept).drop(s.RECORDING_INDEX)


@dataclass(frozen=True)
class TracksPart:
    """The tracks of some of a recording's vehicles (each vehicle with all its rows), and what
    cleaning them counted: a recording is cleaned a part at a time."""

    tracks: pl.DataFrame  # TRACKS_SCHEMA
    report: RecordingReport  # the counts of these vehicles' rows; its speed_* fields unset
    # What the source's recording checks need of these rows, or empty; lazy where a build has
    # staged it (tasks.clean_recording): a recording's evidence is never held whole.
    evidence: pl.DataFrame | pl.LazyFrame


def _claims_no_file(path: Path) -> bool:
    return False


def _knows_no_location(name: str) -> bool:
    return False


def frames_per_step(time_step_s: float, frame_period_s: float) -> int:
    """Frames of `frame_period_s` per grid step of `time_step_s` (2 for NGSIM's 0.1 s frames on
    the 0.2 s grid, 5 for highD's 0.04 s). Raises ValueError for a step of no whole number of
    frames: the grid is kept by frame number, and a step between frames has none on it."""
    frames = round(time_step_s / frame_period_s)
    if frames < 1 or abs(frames * frame_period_s - time_step_s) > 1e-9:
        raise ValueError(
            f"the grid step of {time_step_s:g} s is not a whole number of frames of "
            f"{frame_period_s:g} s ({1 / frame_period_s:g} Hz)"
        )
    return frames


@dataclass(frozen=True)
class Source:
    """A dataset behind the contract: four functions, its frame period, its physical limits,
    the name the manifest records, the drop reasons of its own, and how the registry
    (`sources/registry.py`) tells its files and its locations.

    find_files(paths) -> (files to read, files skipped in the directories searched)
    read_file(path, config, limits, file_index, strict, scratch) -> FileRows, after the file's
        own checks; `scratch` is a folder on the build's disk for files of its own that its rows
        may be scanned from (removed once they are staged)
    vehicle_tracks(rows, key, config, limits, first_track_id) -> TracksPart: the tracks of the
        vehicles of `rows` (all the rows of each, in any order, from any input file), numbered
        from `first_track_id`; the same tracks whichever other vehicles are in the part
    recording_report(parts, key, config, limits, files, strict) -> RecordingReport: the report
        of the recording whose vehicles are those of `parts` (TracksParts, their tracks let go),
        after the recording's checks
    Each is given the build's `limits`: the source's own (`limits`), or others a build was given
    (`pipeline.run_build`'s `limits`).
    claims(path) -> whether the file is one of this dataset's, told from its content; may raise
        NgsimInputError for a damaged file that is still its own (the build refuses it at once)
    is_location(name) -> whether `name` names one of its locations (BuildConfig.locations)
    """

    name: str
    find_files: Callable[[list[Path]], tuple[list[Path], list[Path]]]
    read_file: Callable[[Path, BuildConfig, PhysicalLimits, int, bool, Path | None], FileRows]
    vehicle_tracks: Callable[
        [pl.DataFrame, RecordingKey, BuildConfig, PhysicalLimits, int], TracksPart
    ]
    recording_report: Callable[
        [list[TracksPart], RecordingKey, BuildConfig, PhysicalLimits, list[FileReport], bool],
        RecordingReport,
    ]
    frame_period_s: float  # between two of its frames (NGSIM 0.1 s, highD 0.04 s)
    limits: PhysicalLimits  # what its raw rows may hold: its own, in its own frames
    label: str = ""  # the name a person reads: "NGSIM", "highD"
    suffixes: tuple[str, ...] = ()  # of the files it reads, lower case: a folder search's
    claims: Callable[[Path], bool] = _claims_no_file
    is_location: Callable[[str], bool] = _knows_no_location
    locations_help: str = ""  # its location names, as an error lists them
    # Why its rows are dropped beyond the shared `schema.DropReason`s: value -> what a report
    # says of such rows. Its FileReports count them too, and the manifest by their values.
    drop_reasons: Mapping[str, str] = field(default_factory=dict)

    def frames_per_step(self, time_step_s: float) -> int:
        """Its frames per grid step; ValueError, naming the dataset, for a step of no whole
        number of its frames."""
        try:
            return frames_per_step(time_step_s, self.frame_period_s)
        except ValueError as err:
            raise ValueError(f"{err}, {self.label or self.name}'s frame period") from None


# Every count of a RecordingReport: a new one is summed over the parts too. (A field's type is
# its annotation's text under `from __future__ import annotations`, the class without it;
# test_ngsim_tracks compares the joined counts with those of a whole recording.)
_SUMMED = tuple(
    f.name for f in fields(RecordingReport) if f.type in (int, "int") and f.name[:6] != "speed_"
)


def joined_counts(parts: list[TracksPart], key: RecordingKey) -> RecordingReport:
    """The counts of a recording from those of its parts (disjoint sets of vehicles): sums, and
    the first outlier of all; the speed_* fields are the source's to join."""
    outliers = [p.report.first_outlier for p in parts if p.report.first_outlier is not None]
    return RecordingReport(
        location=key[0],
        period=key[1],
        **{name: sum(getattr(p.report, name) for p in parts) for name in _SUMMED},
        first_outlier=min(outliers) if outliers else None,
    )


def finish_tracks(grid: pl.DataFrame, first_track_id: int, config: BuildConfig) -> pl.DataFrame:
    """The tracks table from a recording's rows on the grid, in SI units, sorted by (vehicle,
    segment, frame): tracks numbered from `first_track_id` in (vehicle, segment) order, the
    heading derived (`kinematics.add_heading`), exactly TRACKS_SCHEMA's columns and dtypes."""
    track_index = pl.struct(s.VEHICLE_ID, s.SEGMENT).rle_id().cast(pl.Int32)
    numbered = grid.with_columns((track_index + first_track_id).alias(s.TRACK_ID))
    tracks = add_heading(numbered, config.smoothing_window_steps, config.min_heading_speed_mps)
    tracks = tracks.select(s.TRACKS_SCHEMA.names()).cast(dict(s.TRACKS_SCHEMA))
    return tracks
