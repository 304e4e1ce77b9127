"""The six official NGSIM recordings and how a recording is recognised from its timestamps.

A recording's key is (location, period). Inside one recording `Global_Time - 100 * Frame_ID` is
constant: it is the epoch time of frame 0. That time names the period: the official period whose
nominal start is nearest, within a tolerance; otherwise a label made of the local clock times.
NGSIM's US-101 and I-80 data were both recorded under Pacific Daylight Time (UTC-7).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError

PACIFIC_DAYLIGHT = timezone(timedelta(hours=-7), "PDT")
FRAME_PERIOD_S = 0.1  # NGSIM's 10 Hz: Global_Time grows 100 ms a frame
MATCH_TOLERANCE_MS = 10 * 60 * 1000
KNOWN_LOCATION_NAMES: tuple[str, ...] = ("us-101", "i-80", "lankershim", "peachtree")
FRAME0_MS = "frame0_epoch_ms"  # Global_Time - 100 * Frame_ID: constant within a recording
_FRAME0 = pl.col(s.GLOBAL_TIME) - 100 * pl.col(s.FRAME_ID).cast(pl.Int64)
# A frame-0 time shared by fewer rows than this share of the largest group of its location is
# not a recording but stray rows (a damaged Global_Time); so is one near a larger group's.
STRAY_GROUP_SHARE = 0.01
MAX_RECORDINGS_PER_FILE = 100


@dataclass(frozen=True)
class Recording:
    """One official recording: location, period label as in the file names, nominal start."""

    location: str
    period: str
    start_epoch_ms: int


def _pdt_ms(year: int, month: int, day: int, hour: int, minute: int) -> int:
    moment = datetime(year, month, day, hour, minute, tzinfo=PACIFIC_DAYLIGHT)
    return int(moment.timestamp() * 1000)


# In the order synth takes them: alternating locations so that two recordings cover both.
OFFICIAL_RECORDINGS: tuple[Recording, ...] = (
    Recording("us-101", "0750am-0805am", _pdt_ms(2005, 6, 15, 7, 50)),
    Recording("i-80", "0400-0415", _pdt_ms(2005, 4, 13, 16, 0)),
    Recording("us-101", "0805am-0820am", _pdt_ms(2005, 6, 15, 8, 5)),
    Recording("i-80", "0500-0515", _pdt_ms(2005, 4, 13, 17, 0)),
    Recording("us-101", "0820am-0835am", _pdt_ms(2005, 6, 15, 8, 20)),
    Recording("i-80", "0515-0530", _pdt_ms(2005, 4, 13, 17, 15)),
)


def is_ngsim_location(name: str) -> bool:
    """Whether `name` is one of NGSIM's locations (KNOWN_LOCATION_NAMES)."""
    return name in KNOWN_LOCATION_NAMES


def find_official_recording(frame0_epoch_ms: int, location: str | None = None) -> Recording | None:
    """The official recording whose nominal start is nearest to frame 0's time, if within 10 min.

    With `location`, only that location's recordings are candidates.
    """
    candidates = [r for r in OFFICIAL_RECORDINGS if location is None or r.location == location]
    best = min(candidates, key=lambda r: abs(r.start_epoch_ms - frame0_epoch_ms), default=None)
    if best is None or abs(best.start_epoch_ms - frame0_epoch_ms) > MATCH_TOLERANCE_MS:
        return None
    return best


def period_label(frame0_epoch_ms: int, last_frame_id: int) -> str:
    """A period label for an unofficial recording: local start and end clock times, 'HHMM-HHMM'."""
    start = datetime.fromtimestamp(frame0_epoch_ms / 1000, PACIFIC_DAYLIGHT)
    end = start + timedelta(milliseconds=100 * last_frame_id)
    return f"{start:%H%M}-{end:%H%M}"


def location_from_path(path: Path) -> str | None:
    """A known location named by a folder or the file name (`US-101/...`, `i80_...`), if any."""
    squeezed = {name.replace("-", ""): name for name in KNOWN_LOCATION_NAMES}
    for part in reversed(path.parts):
        token = part.lower().replace("-", "").replace("_", "")
        for key, name in squeezed.items():
            if key in token:
                return name
    return None


def _name_recording(
    frame0_ms: int, last_frame: int, location: str | None, path: Path
) -> tuple[str, str]:
    official = find_official_recording(frame0_ms, location)
    if official is not None:
        return official.location, official.period
    named = location or location_from_path(path)
    if named is None:
        start = datetime.fromtimestamp(frame0_ms / 1000, PACIFIC_DAYLIGHT)
        raise NgsimInputError(
            path,
            f"cannot tell the location: frame 0 at {start:%Y-%m-%d %H:%M} PDT is none of the "
            "official NGSIM periods; put the file in a folder named after its location "
            f"({', '.join(KNOWN_LOCATION_NAMES)})",
        )
    return named, period_label(frame0_ms, last_frame)


def _names_another_location(frame0_ms: int, file_location: str | None) -> bool:
    """Whether a frame-0 time names an official period of another location than
    `file_location`, the location of a file whose rows do not say theirs (a per-location or
    per-period file holds one location's rows: its largest group's)."""
    official = find_official_recording(frame0_ms)
    return file_location is not None and official is not None and official.location != file_location


# A group of rows that share a frame-0 time, other than its location's largest, is a recording
# only with this many vehicles: fewer are stray rows (a damaged Global_Time, such as one
# vehicle's record an hour off, which names an official period of its own), however far from
# the others and whatever period they name. A group that by its time alone would be stray rows
# (small, near a larger group's, or of its name) is a clock of its own, a recording, when this
# many whole vehicles have no row in a larger group and hold nearly all of its rows: stray rows
# are rows of vehicles recorded on another clock too, never whole vehicles.
MIN_RECORDING_VEHICLES = 20
MIN_CLOCK_OWN_SHARE = 0.9


def _frame0_groups(frame: pl.LazyFrame) -> tuple[pl.DataFrame, pl.DataFrame]:
    """(location, frame-0 time) groups of rows with their row count, last frame and vehicle
    count, the largest of each location first, and whether each is too small to be a recording
    of its own; and the rows of each vehicle in each group (location, frame-0 time, vehicle id,
    rows)."""
    per_vehicle = (
        frame.select(s.LOCATION, _FRAME0.alias(FRAME0_MS), s.FRAME_ID, s.VEHICLE_ID)
        .drop_nulls(FRAME0_MS)
        .group_by(s.LOCATION, FRAME0_MS, s.VEHICLE_ID)
        .agg(pl.len().alias("rows"), pl.col(s.FRAME_ID).max().alias("last_frame"))
        .collect(engine="streaming")  # morsel by morsel: no copy of a large file's keys
    )
    groups = (
        per_vehicle.group_by(s.LOCATION, FRAME0_MS)
        .agg(pl.col("rows").sum(), pl.col("last_frame").max(), pl.len().alias("vehicles"))
        .sort(s.LOCATION, "rows", FRAME0_MS, descending=[False, True, False], nulls_last=True)
    )
    small = pl.col("rows") < STRAY_GROUP_SHARE * pl.col("rows").max().over(s.LOCATION)
    return groups.with_columns(small.alias("small")), per_vehicle.drop("last_frame")


def is_a_recording(vehicles: int, their_rows: int, rows: int) -> bool:
    """The rule of a group of rows (`rows` of them) that is not its location's largest: a
    recording only when `vehicles` vehicles (at least MIN_RECORDING_VEHICLES), holding
    `their_rows` of its rows (at least MIN_CLOCK_OWN_SHARE of them), are its own."""
    return vehicles >= MIN_RECORDING_VEHICLES and their_rows >= MIN_CLOCK_OWN_SHARE * rows


def _own_vehicles(
    per_vehicle: pl.DataFrame, groups: pl.DataFrame, position: int
) -> tuple[list[int], int]:
    """The vehicles of group `position` that have no row in a larger group of its location, and
    their rows."""
    location, frame0_ms = groups.row(position)[:2]
    of_location = per_vehicle.filter(pl.col(s.LOCATION).eq_missing(location))
    larger = groups.head(position).filter(pl.col(s.LOCATION).eq_missing(location))[FRAME0_MS]
    elsewhere = of_location.filter(pl.col(FRAME0_MS).is_in(larger.implode()))[s.VEHICLE_ID]
    own = of_location.filter(
        (pl.col(FRAME0_MS) == frame0_ms) & ~pl.col(s.VEHICLE_ID).is_in(elsewhere.implode())
    )
    return sorted(own[s.VEHICLE_ID].to_list()), int(own["rows"].sum())


def identify_recordings(
    frame: pl.DataFrame, path: Path, usable: pl.Series | None = None
) -> tuple[pl.Series, list[tuple[str, str]]]:
    """Which recording each raw row belongs to: (index per row, (location, period) per index);
    see `recording_index`."""
    rows = frame.lazy() if usable is None else frame.lazy().with_columns(usable.alias(_USABLE))
    index, keys, _ = recording_index(rows, path, None if usable is None else pl.col(_USABLE))
    return frame.select(index.alias(s.RECORDING_INDEX)).to_series(), keys


_USABLE = "__usable"


def _distinct(key: tuple[str, str], keys: list[tuple[str, str]]) -> tuple[str, str]:
    """`key`, or its period with the first free suffix -2, -3, ... if a recording has it."""
    location, period = key
    n = 1
    while key in keys:
        n += 1
        key = (location, f"{period}-{n}")
    return key


def recording_index(
    frame: pl.LazyFrame, path: Path, usable: pl.Expr | None = None
) -> tuple[pl.Expr, list[tuple[str, str]], dict[tuple[str, str], str]]:
    """Which recording each raw row belongs to: (an expression of each row's index, the
    (location, period) of each index, a line for each recording told apart by its own clock).

    `frame` needs global_time, frame_id, vehicle_id and location (null where the file does not
    say, as in per-period files). Rows of one file that differ in `Global_Time - 100 * Frame_ID`
    belong to different recordings (the combined CSV holds three periods per location), unless
    they are strays: a group other than its location's largest with fewer than
    MIN_RECORDING_VEHICLES vehicles (`is_a_recording`), whatever period it names; or rows whose
    frame-0 time lies within MATCH_TOLERANCE_MS of a larger group's, names the same recording
    as a larger group, or is shared by few rows (under STRAY_GROUP_SHARE of the location's
    largest group), unless they are a clock of their own (MIN_RECORDING_VEHICLES whole vehicles
    and nearly all its rows theirs): a recording, its period suffixed (-2, ...) if a larger
    group has the same name, and said in the lines returned. Where the rows do not say their
    location (all but the portal CSV), the largest group's location is the file's, and a group
    whose frame-0 time names an official period of another location is stray whatever its size.
    A stray row's index is null, as is that of a row without a time or frame; the caller counts
    and drops them. Only the `usable` rows (a bool expression; all by default) form recordings;
    the others get the index of the recording whose frame-0 time they share, if any. Recordings
    are indexed in (location, frame-0 time) order.
    """
    accepted: list[tuple[str | None, int, int]] = []  # location, frame-0 time, group position
    keys: list[tuple[str, str]] = []
    own: dict[int, list[int]] = {}  # by accepted position: the only vehicles of a clock's rows
    notes: dict[tuple[str, str], str] = {}
    groups, per_vehicle = _frame0_groups(frame if usable is None else frame.filter(usable))
    file_location: str | None = None  # of rows that do not say theirs: the largest group's
    for position, group in enumerate(groups.iter_rows(named=True)):
        location, frame0_ms = group[s.LOCATION], group[FRAME0_MS]
        if location is None and _names_another_location(frame0_ms, file_location):
            continue  # stray rows: another location's recording inside this location's file
        near = [
            (loc, ms) for loc, ms, _ in accepted
            if loc == location and abs(ms - frame0_ms) <= MATCH_TOLERANCE_MS
        ]  # fmt: skip
        largest = not any(loc == location for loc, _, _ in accepted)
        stray = bool(near) or group["small"]
        if not (
            stray or largest or is_a_recording(group["vehicles"], group["rows"], group["rows"])
        ):
            continue  # stray rows: too few vehicles for a recording, wherever their time lies
        key = None if stray else _name_recording(frame0_ms, group["last_frame"], location, path)
        if stray or key in keys:
            vehicles, rows = _own_vehicles(per_vehicle, groups, position)
            if not is_a_recording(len(vehicles), rows, group["rows"]):
                continue  # stray rows
            key = key or _name_recording(frame0_ms, group["last_frame"], location, path)
            own[len(keys)] = vehicles
            if near or key in keys:
                key = _distinct(key, keys)
                notes[key] = _clock_note(group, key, len(vehicles), rows, near, accepted, keys)
        if len(keys) == MAX_RECORDINGS_PER_FILE:
            raise NgsimInputError(
                path,
                f"more than {MAX_RECORDINGS_PER_FILE} recordings (distinct values of Global_Time - "
                "100 * Frame_ID): is the Global_Time or Frame_ID column damaged?",
            )
        accepted.append((location, frame0_ms, position))
        keys.append(key)
        if location is None and file_location is None:
            file_location = key[0]
    order = sorted(
        range(len(keys)),
        key=lambda i: (accepted[i][0] is None, accepted[i][0] or "", accepted[i][1]),
    )
    # A row takes the index of the accepted group it shares (location, frame-0 time) with (of a
    # clock's group, only its own vehicles' rows); one test per recording, a handful, rather
    # than a join that copies every row's keys.
    index = pl.lit(None, dtype=pl.UInt16)
    for new, i in enumerate(order):
        location, frame0_ms, _ = accepted[i]
        same = pl.col(s.LOCATION).eq_missing(pl.lit(location, dtype=pl.String)) & (
            _FRAME0.eq(frame0_ms)
        )
        if i in own:
            same &= pl.col(s.VEHICLE_ID).is_in(own[i])
        index = pl.when(same).then(pl.lit(new, dtype=pl.UInt16)).otherwise(index)
    if not order:  # no recording: a null of each row, not a lone literal
        return pl.repeat(None, pl.len(), dtype=pl.UInt16), [], notes
    return index, [keys[i] for i in order], notes


def _clock_note(
    group: dict,
    key: tuple[str, str],
    vehicles: int,
    rows: int,
    near: list[tuple[str | None, int]],
    accepted: list[tuple[str | None, int, int]],
    keys: list[tuple[str, str]],
) -> str:
    """What a build says of a recording told apart by its own clock: which, how many vehicles,
    and how far from the recording it would otherwise have joined."""
    same_name = [
        (loc, ms) for (loc, ms, _), k in zip(accepted, keys, strict=True) if k[0] == key[0]
    ]
    other = near[0] if near else same_name[0]
    other_key = keys[[(loc, ms) for loc, ms, _ in accepted].index(other)]
    seconds = (group[FRAME0_MS] - other[1]) / 1000
    return (
        f"{key[0]}/{key[1]}: {vehicles:,} vehicles ({rows:,} rows) keep a frame clock of their "
        f"own, Global_Time - 100 * Frame_ID {seconds:+.1f} s from {other_key[0]}/{other_key[1]}'s: "
        "a recording of their own, not stray rows"
    )
