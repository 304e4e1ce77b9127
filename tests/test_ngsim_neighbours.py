"""The neighbour and headway columns against the rows' positions (sources/ngsim/neighbours.py):
swapped or foreign columns refused by name through `ngsim-graphs build`, with statistics a
person can compute; NGSIM's sentinels and the synthetic files with their quirks pass."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from conftest import make_row, write_period_csv, write_portal, write_txt
from test_cli_ngsim import assert_failed_cleanly, invoke

from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.schema import RawFormat
from ngsim_graphs.sources.ngsim import neighbours as nb
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.plausibility import LIMITS
from ngsim_graphs.sources.ngsim.recordings import KNOWN_LOCATION_NAMES
from ngsim_graphs.sources.ngsim.tracks import read_file
from ngsim_graphs.synth import formats as synthesis

FT = 0.3048
GAP_FT, SPEED_FPS = 60.0, 35.0
TIME_HEADWAY_S = round(GAP_FT / SPEED_FPS, 2)  # 1.71
NAME = "recording us-101/0750am-0805am: "


def platoon(frames: int = 100) -> list[dict]:
    """Vehicles 1..20 of us-101 0750am, frames 0..`frames` - 1: vehicle v in lane
    (v - 1) % 5 + 1 at its centre, four a lane 60 ft apart (front to front), all at 35 ft/s.
    Vehicle v's Preceding is v + 5 and its Following v - 5 where that vehicle is in its lane,
    Space_Headway 60 ft and Time_Headway 1.71 s behind a leader (0 and 9999.99 without one,
    NGSIM's sentinels). In the frames the checks compare (every 10th: 10 of 100), 150 rows
    name a Preceding vehicle and 150 a Following one."""
    rows = []
    for v in range(1, 21):
        lane, place = (v - 1) % 5 + 1, (v - 1) // 5  # place 0 at the back, 3 in front
        led, leads = place < 3, place > 0
        rows += [
            make_row(
                v, f, local_x_ft=6.0 + 12.0 * (lane - 1), local_y_ft=GAP_FT * place + 3.5 * f,
                v_vel_fps=SPEED_FPS, lane_id=lane,
                preceding=v + 5 if led else 0, following=v - 5 if leads else 0,
                space_headway=GAP_FT if led else 0.0,
                time_headway=TIME_HEADWAY_S if led else ns.NO_LEADER_TIME_HEADWAY_S,
            )
            for f in range(frames)
        ]  # fmt: skip
    return rows


def refused(tmp_path: Path, rows: list[dict], message: str) -> None:
    """A build of `rows` (a .txt) fails with the one line `path: message`, writing nothing."""
    path, out = write_txt(tmp_path / "a.txt", rows), tmp_path / "out"
    line = assert_failed_cleanly(invoke("build", path, "--out", out), out, {}, path, message)
    assert line == f"error: {path}: {message}"


def test_a_platoon_passes_with_the_statistics_a_person_computes(tmp_path: Path) -> None:
    path = write_txt(tmp_path / "a.txt", platoon())
    read = read_file(path, BuildConfig(), LIMITS, 0, strict=True)
    sample = nb.sampled_rows(read.rows)
    assert sample.height == 200 and sorted(sample[s.FRAME_ID].unique()) == list(range(0, 100, 10))
    assert sample["__direction"].unique().to_list() == [1]  # everyone drives along +y
    preceding = nb.neighbour_statistics(sample, s.PRECEDING).row(0, named=True)
    assert preceding == {
        s.RECORDING_INDEX: 0, "ids": 150, "known": 1.0, "named": 150, "there": 1.0,
        "moving": 150, "ahead": 1.0, "behind": 0.0,
    }  # fmt: skip
    following = nb.neighbour_statistics(sample, s.FOLLOWING).row(0, named=True)
    assert (following["named"], following["ahead"], following["behind"]) == (150, 0.0, 1.0)
    spacing = nb.spacing_statistics(sample).row(0, named=True)
    assert (spacing["found"], spacing["spaced"], spacing["timed"]) == (150, 150, 150)
    assert spacing["distance_m"] == pytest.approx(GAP_FT * FT)
    assert spacing["mismatch_m"] == 0.0
    assert spacing["time_mismatch_m"] == pytest.approx((GAP_FT - TIME_HEADWAY_S) * FT)
    headways = nb.headway_statistics(sample).row(0, named=True)
    assert headways["timed"] == 150
    assert headways["ratio"] == pytest.approx(TIME_HEADWAY_S * SPEED_FPS / GAP_FT)  # 0.9975


def test_space_and_time_headway_swapped_are_refused(tmp_path: Path) -> None:
    # e01: the two columns swapped in every row: each value plausible (9999.99 ft is 3 km).
    rows = [
        {**r, ns.SPACE_HEADWAY: r[ns.TIME_HEADWAY], ns.TIME_HEADWAY: r[ns.SPACE_HEADWAY]}
        for r in platoon()
    ]
    refused(
        tmp_path, rows,
        f"{NAME}Space_Headway and Time_Headway look swapped: Time_Headway, not Space_Headway, "
        "is the distance to the Preceding vehicle: over the 150 rows that find it in their "
        "frame, Time_Headway differs from it by 0.0 m at the median and Space_Headway by 17.8 m "
        "(median distance 18.3 m, 5.6 m allowed)",
    )  # fmt: skip


def test_preceding_and_following_swapped_are_refused(tmp_path: Path) -> None:
    # e01: each "preceding" vehicle is the row's follower, 60 ft behind it, and vice versa.
    rows = [{**r, s.PRECEDING: r[s.FOLLOWING], s.FOLLOWING: r[s.PRECEDING]} for r in platoon()]
    refused(
        tmp_path, rows,
        f"{NAME}Preceding and Following look swapped: the Preceding vehicle is ahead of the "
        "row's vehicle (in its direction of travel) in 0.0% of 150 rows, the Following one "
        "behind it in 0.0% of 150 (at least 50% expected)",
    )  # fmt: skip


def test_a_neighbour_column_of_another_columns_values_is_refused(tmp_path: Path) -> None:
    # Preceding holds v_Class (2) in every row: vehicle 2 is in every frame, but in lane 2,
    # where 4 of the 20 vehicles drive (itself among them).
    refused(
        tmp_path, [{**r, s.PRECEDING: r[s.V_CLASS]} for r in platoon()],
        f"{NAME}Preceding is mostly not a vehicle of the row's frame and lane: 20.0% of the 200 "
        "rows that name a vehicle of the recording find it there (at least 50% expected); is "
        "Preceding another column's?",
    )  # fmt: skip
    # Following holds Total_Frames (100): no vehicle of the recording.
    refused(
        tmp_path, [{**r, s.FOLLOWING: r[ns.TOTAL_FRAMES]} for r in platoon()],
        f"{NAME}Following is mostly no vehicle of the recording: 0.0% of the 200 rows that name "
        "one name a vehicle of its rows in the file (at least 25% expected); is Following "
        "another column's?",
    )  # fmt: skip


def test_a_lone_neighbour_column_pointing_the_wrong_way_is_refused(tmp_path: Path) -> None:
    # Following names the vehicle ahead (Preceding's values) and Preceding is kept.
    refused(
        tmp_path, [{**r, s.FOLLOWING: r[s.PRECEDING]} for r in platoon()],
        f"{NAME}Following is mostly not the vehicle behind the row's: it is in 0.0% of 150 rows "
        "(at least 50% expected); is Following another column's?",
    )  # fmt: skip


def test_headways_in_other_units_are_refused(tmp_path: Path) -> None:
    # Space_Headway in metres (18.288 for 60 ft): 41.7 ft short of the distance.
    rows = [{**r, ns.SPACE_HEADWAY: round(r[ns.SPACE_HEADWAY] * FT, 3)} for r in platoon()]
    refused(
        tmp_path, rows,
        f"{NAME}Space_Headway is not the distance to the Preceding vehicle: they differ by "
        "12.7 m at the median of 150 rows (median distance 18.3 m, 5.6 m allowed); is "
        "Space_Headway another column's, or in other units than feet?",
    )  # fmt: skip
    # Time_Headway in minutes (0.029 for 1.71 s): 0.029 * 35 / 60 = 0.017.
    rows = [
        {**r, ns.TIME_HEADWAY: round(r[ns.TIME_HEADWAY] / 60, 3)} if r[s.PRECEDING] else r
        for r in platoon()
    ]
    refused(
        tmp_path, rows,
        f"{NAME}Time_Headway is not Space_Headway / v_Vel: Time_Headway * v_Vel / Space_Headway "
        "is 0.02 at the median of 150 rows (0.5 to 2 allowed, 1 by definition); is Time_Headway "
        "another column's, or in other units than seconds?",
    )  # fmt: skip


def test_ngsim_sentinels_a_standstill_and_noise_pass(tmp_path: Path) -> None:
    """Behind a leader at a standstill Time_Headway is 9999.99 (NGSIM's), and in front there is
    no Preceding vehicle (0) and Space_Headway 0. And noise: of the rows with a leader, a third
    have Space_Headway 20 % off and Time_Headway left empty, and a third (of the lanes 1..4)
    name the vehicle ahead in the next lane (as during a lane change)."""
    rows = platoon()
    for i, row in enumerate(rows):
        f, v = row[s.FRAME_ID], row[s.VEHICLE_ID]
        if f >= 40:  # the platoon halts for 2 s, then drives on
            row[ns.LOCAL_Y] -= 3.5 * (min(f, 60) - 40)
        if 40 <= f < 60:
            row[ns.V_VEL] = 0.0
            if row[s.PRECEDING]:
                row[ns.TIME_HEADWAY] = ns.NO_LEADER_TIME_HEADWAY_S
        if row[s.PRECEDING] and i % 3 == 0:
            row[ns.SPACE_HEADWAY] *= 1.2
            row[ns.TIME_HEADWAY] = None
        if row[s.PRECEDING] and i % 3 == 1 and v % 5 != 0:
            row[s.PRECEDING] = v + 6
    path, out = write_period_csv(tmp_path / "a.csv", rows), tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output
    sample = nb.sampled_rows(read_file(path, BuildConfig(), LIMITS, 0, strict=True).rows)
    there = nb.neighbour_statistics(sample, s.PRECEDING)["there"].item()
    assert 0.5 < there < 0.8


@pytest.mark.parametrize("write", [write_txt, write_period_csv, write_portal])
def test_the_platoon_builds_in_every_format(tmp_path: Path, write) -> None:
    path, out = write(tmp_path / "trajectories-0750am-0805am.csv", platoon()), tmp_path / "out"
    result = invoke("build", path, "--out", out)
    assert result.exit_code == 0, result.output


_simulated: dict[tuple[str, str, float, int], pl.DataFrame] = {}


@pytest.fixture
def simulate_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Simulate each recording once for the formats below; the simulation has its own tests."""
    simulate = synthesis.simulate_recording

    def cached(recording, minutes, seed):  # noqa: ANN001, ANN202
        key = (recording.location, recording.period, minutes, seed)
        if key not in _simulated:
            _simulated[key] = simulate(recording, minutes, seed)
        return _simulated[key]

    monkeypatch.setattr(synthesis, "simulate_recording", cached)


@pytest.mark.usefixtures("simulate_once")
@pytest.mark.parametrize("quirks", [False, True])
@pytest.mark.parametrize("raw_format", [RawFormat.TXT, RawFormat.CSV, RawFormat.PORTAL])
def test_synthetic_files_pass_the_checks_and_are_judged(
    tmp_path: Path, raw_format: RawFormat, quirks: bool
) -> None:
    """Every synthetic format, with and without the quirks of real exports (frame gaps,
    duplicates, empty fields, a foreign location): each file's checks pass, and each of its
    recordings has the rows to be judged by every one of them."""
    config = SynthConfig(raw_format, 2, 0.3, 7, quirks)
    paths = synthesis.write_synthetic(tmp_path / "raw", config)
    build = BuildConfig(locations=KNOWN_LOCATION_NAMES)
    for path in (p for p in paths if p.suffix in (".txt", ".csv")):
        read = read_file(path, build, LIMITS, 0, strict=False)
        sample = nb.sampled_rows(read.rows)
        for column in (s.PRECEDING, s.FOLLOWING):
            stats = nb.neighbour_statistics(sample, column)
            assert stats.height == len(read.recordings)
            assert stats["moving"].min() >= nb.MIN_NEIGHBOUR_ROWS
        assert nb.spacing_statistics(sample)["spaced"].min() >= nb.MIN_NEIGHBOUR_ROWS
        assert nb.headway_statistics(sample)["timed"].min() >= nb.MIN_NEIGHBOUR_ROWS
