"""The neighbour and headway columns against the rows' positions: a recording whose Preceding,
Following, Space_Headway or Time_Headway is not what its header says (docs/trust.md).

Swapped in every row (Space_Headway with Time_Headway, Preceding with Following), each value is
plausible and passes every row check. Their relations to the other columns are not: a row's
Preceding vehicle is a vehicle of its frame and lane, ahead of the row's vehicle in its
direction of travel, and its Following vehicle one behind it; Space_Headway is the distance
between their fronts (ft) and Time_Headway is Space_Headway / v_Vel (s). Each relation is judged
by a whole-recording statistic, a share or a median, over the rows of every
NEIGHBOUR_FRAME_STRIDE-th frame: whole frames, so that a row's neighbours are there, and a
bounded part of a large file. NGSIM's sentinels are no neighbour: 0 for no Preceding or
Following vehicle (and Space_Headway 0 without a leader), Time_Headway 9999.99 at a standstill.
Rows in NGSIM's units (feet, seconds).
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.contract import FileRows
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.cleaning import FEET_TO_M

NEIGHBOUR_FRAME_STRIDE = 10  # frames whose rows are compared: every 10th (1 s at 10 Hz)
MIN_NEIGHBOUR_ROWS = 50  # fewer rows say too little to judge a column
# At least this share of the rows that name a vehicle of the recording must find it in their
# frame and lane, and of those whose vehicle moves, the Preceding one ahead, the Following one
# behind (real rows: nearly all; swapped columns: nearly none).
MIN_NEIGHBOUR_SHARE = 0.5
# At least this share of the rows that name a neighbour must name a vehicle of the file's rows
# of the recording: all of them in a recording's file, half where its vehicles are split
# between two files; another column's values mostly name none.
MIN_KNOWN_SHARE = 0.25
# Space_Headway must be the distance to the Preceding vehicle's front: the median difference
# at most this plus this share of the median distance (Space_Headway in metres: 70 % off).
MAX_SPACING_MISMATCH_M = 1.0
MAX_SPACING_MISMATCH_SHARE = 0.25
# Time_Headway * v_Vel / Space_Headway, 1 by NGSIM's definition, at its median within these.
TIME_HEADWAY_RATIO = (0.5, 2.0)

_Y, _LANE, _KNOWN = "__neighbour_y", "__neighbour_lane", "__neighbour_known"
_DIRECTION = "__direction"
_SAMPLED = (
    s.RECORDING_INDEX, s.VEHICLE_ID, s.FRAME_ID, ns.LOCAL_Y, s.LANE_ID, ns.V_VEL,
    s.PRECEDING, s.FOLLOWING, ns.SPACE_HEADWAY, ns.TIME_HEADWAY,
)  # fmt: skip


def sampled_rows(rows: pl.LazyFrame) -> pl.DataFrame:
    """The rows of every NEIGHBOUR_FRAME_STRIDE-th frame that a recording keeps (RECORDING_INDEX
    not null), with the columns the checks read and each vehicle's direction of travel along
    Local_Y over them (+1, -1; 0 where it does not move or has one such row)."""
    sample = (
        rows.filter(
            pl.col(s.RECORDING_INDEX).is_not_null()
            & (pl.col(s.FRAME_ID) % NEIGHBOUR_FRAME_STRIDE == 0)
        )
        .select(_SAMPLED)
        .collect(engine="streaming")
    )
    y, frame = pl.col(ns.LOCAL_Y), pl.col(s.FRAME_ID)
    travel = y.get(frame.arg_max()) - y.get(frame.arg_min())
    vehicle = (s.RECORDING_INDEX, s.VEHICLE_ID)
    return sample.with_columns(travel.over(vehicle).sign().fill_null(0).alias(_DIRECTION))


def _with_neighbour(sample: pl.DataFrame, column: str) -> pl.DataFrame:
    """The rows of `sample` whose `column` (PRECEDING or FOLLOWING) names a vehicle (above 0),
    with whether the sample holds that vehicle in the row's recording (_KNOWN) and its Local_Y
    and Lane_ID in the row's frame (null where it has no row there)."""
    key = [s.RECORDING_INDEX, s.FRAME_ID]
    vehicles = sample.select(s.RECORDING_INDEX, pl.col(s.VEHICLE_ID).alias(column)).unique()
    neighbours = sample.select(
        *key, pl.col(s.VEHICLE_ID).alias(column), pl.col(ns.LOCAL_Y).alias(_Y),
        pl.col(s.LANE_ID).alias(_LANE),
    )  # fmt: skip
    known = vehicles.with_columns(pl.lit(True).alias(_KNOWN))
    return (
        sample.filter(pl.col(column) > 0)
        .join(known, on=[s.RECORDING_INDEX, column], how="left")
        .join(neighbours, on=[*key, column], how="left")
        .with_columns(pl.col(_KNOWN).fill_null(False))
    )


def neighbour_statistics(sample: pl.DataFrame, column: str) -> pl.DataFrame:
    """Per recording of `sample` (from sampled_rows), of the rows whose `column` (PRECEDING or
    FOLLOWING) names a vehicle: how many ("ids") and the share of them naming a vehicle the
    sample holds in the recording ("known"); of those, how many ("named") and the share that
    find it in their frame and lane ("there"); of those found whose vehicle moves, how many
    ("moving") and the shares whose neighbour lies ahead of them in their direction of travel
    ("ahead") and behind them ("behind")."""
    known = pl.col(_KNOWN)
    found = known & pl.col(_Y).is_not_null()
    moving = found & (pl.col(_DIRECTION) != 0)
    along = (pl.col(_Y) - pl.col(ns.LOCAL_Y)) * pl.col(_DIRECTION)
    return (
        _with_neighbour(sample, column)
        .group_by(s.RECORDING_INDEX)
        .agg(
            pl.len().alias("ids"),
            known.mean().alias("known"),
            known.sum().alias("named"),
            (found & (pl.col(_LANE) == pl.col(s.LANE_ID)))
            .fill_null(False)
            .filter(known)
            .mean()
            .alias("there"),
            moving.sum().alias("moving"),
            (along > 0).filter(moving).mean().alias("ahead"),
            (along < 0).filter(moving).mean().alias("behind"),
        )
    )


def spacing_statistics(sample: pl.DataFrame) -> pl.DataFrame:
    """Per recording of `sample`, of the rows whose Preceding vehicle is in their frame: how
    many ("found") and the median distance between the two fronts ("distance_m"); how many have
    a Space_Headway above 0 ("spaced") and its median difference from that distance
    ("mismatch_m"); and the median difference of Time_Headway from it, as if it were one too,
    where it is above 0 and under 9999.99 ("time_mismatch_m": small where the two are swapped);
    in m."""
    distance = (pl.col(_Y) - pl.col(ns.LOCAL_Y)).abs()
    space, time = pl.col(ns.SPACE_HEADWAY), pl.col(ns.TIME_HEADWAY)
    spaced = space > 0
    timed = (time > 0) & (time < ns.NO_LEADER_TIME_HEADWAY_S)
    return (
        _with_neighbour(sample, s.PRECEDING)
        .filter(pl.col(_Y).is_not_null())
        .group_by(s.RECORDING_INDEX)
        .agg(
            pl.len().alias("found"),
            (distance.median() * FEET_TO_M).alias("distance_m"),
            spaced.sum().alias("spaced"),
            ((space - distance).abs().filter(spaced).median() * FEET_TO_M).alias("mismatch_m"),
            timed.sum().alias("timed"),
            ((time - distance).abs().filter(timed).median() * FEET_TO_M).alias("time_mismatch_m"),
        )
    )


def headway_statistics(sample: pl.DataFrame) -> pl.DataFrame:
    """Per recording of `sample`, over the rows with a Preceding vehicle, Space_Headway, v_Vel
    and Time_Headway above 0 and Time_Headway under NGSIM's 9999.99: how many ("timed"), the
    median of Time_Headway * v_Vel / Space_Headway ("ratio", 1 by definition) and of
    Space_Headway * v_Vel / Time_Headway ("swapped_ratio", 1 where the two are swapped)."""
    space, time, speed = pl.col(ns.SPACE_HEADWAY), pl.col(ns.TIME_HEADWAY), pl.col(ns.V_VEL)
    timed = (
        (pl.col(s.PRECEDING) > 0)
        & (space > 0)
        & (speed > 0)
        & (time > 0)
        & (time < ns.NO_LEADER_TIME_HEADWAY_S)
    )
    return (
        sample.filter(timed)
        .group_by(s.RECORDING_INDEX)
        .agg(
            pl.len().alias("timed"),
            (time * speed / space).median().alias("ratio"),
            (space * speed / time).median().alias("swapped_ratio"),
        )
    )


def _of(table: pl.DataFrame, index: int) -> dict:
    """The statistics of recording `index` (an empty dict if it has none)."""
    rows = table.filter(pl.col(s.RECORDING_INDEX) == index)
    return rows.row(0, named=True) if rows.height else {}


def _judged(stats: dict, count: str) -> bool:
    """Whether the statistics `stats` rest on enough rows (their `count`) to judge a column."""
    return stats.get(count, 0) >= MIN_NEIGHBOUR_ROWS


def _ids_problem(name: str, stats: dict) -> str | None:
    """What is wrong with the neighbour ids of column `name` (its neighbour_statistics), if
    anything: ids that are no vehicle of the recording, or not one of the row's frame and
    lane."""
    if _judged(stats, "ids") and stats["known"] < MIN_KNOWN_SHARE:
        return (
            f"{name} is mostly no vehicle of the recording: {stats['known']:.1%} of the "
            f"{stats['ids']:,} rows that name one name a vehicle of its rows in the file (at "
            f"least {MIN_KNOWN_SHARE:.0%} expected); is {name} another column's?"
        )
    if _judged(stats, "named") and stats["there"] < MIN_NEIGHBOUR_SHARE:
        return (
            f"{name} is mostly not a vehicle of the row's frame and lane: {stats['there']:.1%} "
            f"of the {stats['named']:,} rows that name a vehicle of the recording find it there "
            f"(at least {MIN_NEIGHBOUR_SHARE:.0%} expected); is {name} another column's?"
        )
    return None


def _neighbour_ids_problem(preceding: dict, following: dict) -> str | None:
    """What is wrong with the Preceding and Following ids of one recording (their
    neighbour_statistics), if anything."""
    problem = _ids_problem("Preceding", preceding) or _ids_problem("Following", following)
    if problem is not None:
        return problem
    ahead = preceding["ahead"] if _judged(preceding, "moving") else None
    behind = following["behind"] if _judged(following, "moving") else None
    wrong = [share is not None and share < MIN_NEIGHBOUR_SHARE for share in (ahead, behind)]
    if all(wrong):
        return (
            f"Preceding and Following look swapped: the Preceding vehicle is ahead of the row's "
            f"vehicle (in its direction of travel) in {ahead:.1%} of {preceding['moving']:,} "
            f"rows, the Following one behind it in {behind:.1%} of {following['moving']:,} (at "
            f"least {MIN_NEIGHBOUR_SHARE:.0%} expected)"
        )
    for name, share, stats, where in (
        ("Preceding", ahead, preceding, "ahead of"),
        ("Following", behind, following, "behind"),
    ):
        if share is not None and share < MIN_NEIGHBOUR_SHARE:
            return (
                f"{name} is mostly not the vehicle {where} the row's: it is in {share:.1%} of "
                f"{stats['moving']:,} rows (at least {MIN_NEIGHBOUR_SHARE:.0%} expected); is "
                f"{name} another column's?"
            )
    return None


def _headway_problem(spacing: dict, headways: dict) -> str | None:
    """What is wrong with the Space_Headway and Time_Headway of one recording, if anything."""
    low, high = TIME_HEADWAY_RATIO
    if _judged(spacing, "spaced"):
        distance = spacing["distance_m"]
        allowed = MAX_SPACING_MISMATCH_M + MAX_SPACING_MISMATCH_SHARE * distance
        mismatch, time_mismatch = spacing["mismatch_m"], spacing["time_mismatch_m"]
        if mismatch > allowed and _judged(spacing, "timed") and time_mismatch <= allowed:
            return (
                f"Space_Headway and Time_Headway look swapped: Time_Headway, not Space_Headway, "
                f"is the distance to the Preceding vehicle: over the {spacing['found']:,} rows "
                f"that find it in their frame, Time_Headway differs from it by "
                f"{time_mismatch:.1f} m at the median and Space_Headway by {mismatch:.1f} m "
                f"(median distance {distance:.1f} m, {allowed:.1f} m allowed)"
            )
        if mismatch > allowed:
            return (
                f"Space_Headway is not the distance to the Preceding vehicle: they differ by "
                f"{mismatch:.1f} m at the median of {spacing['spaced']:,} rows (median distance "
                f"{distance:.1f} m, {allowed:.1f} m allowed); is Space_Headway another column's, "
                "or in other units than feet?"
            )
    if not _judged(headways, "timed") or low <= headways["ratio"] <= high:
        return None
    ratio, swapped = headways["ratio"], headways["swapped_ratio"]
    hint = " (swapped with Space_Headway?)" if low <= swapped <= high else ""
    return (
        f"Time_Headway is not Space_Headway / v_Vel: Time_Headway * v_Vel / Space_Headway is "
        f"{ratio:.2f} at the median of {headways['timed']:,} rows ({low:g} to {high:g} allowed, "
        f"1 by definition); is Time_Headway another column's{hint}, or in other units than "
        "seconds?"
    )


def check_neighbours(path: Path, read: FileRows) -> None:
    """Raise naming `path` and the recording when a recording of the file has Preceding,
    Following, Space_Headway or Time_Headway columns that are not what they say (swapped with
    each other or another column, other units): see the module's rules."""
    if not read.recordings:
        return
    sample = sampled_rows(read.rows)
    preceding = neighbour_statistics(sample, s.PRECEDING)
    following = neighbour_statistics(sample, s.FOLLOWING)
    spacing, headways = spacing_statistics(sample), headway_statistics(sample)
    for (location, period), index in sorted(read.recordings.items(), key=lambda kv: kv[1]):
        problem = _neighbour_ids_problem(
            _of(preceding, index), _of(following, index)
        ) or _headway_problem(_of(spacing, index), _of(headways, index))
        if problem is not None:
            raise NgsimInputError(path, f"recording {location}/{period}: {problem}")
