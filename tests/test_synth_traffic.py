"""The traffic simulation behind `synth`: NGSIM-shaped, consistent and deterministic rows."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from ngsim_graphs import schema
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS, Recording
from ngsim_graphs.synth.road import ROADWAYS
from ngsim_graphs.synth.traffic import simulate_recording

US101, I80 = OFFICIAL_RECORDINGS[0], OFFICIAL_RECORDINGS[1]
MAX_SPEED_FPS = 45.0 / 0.3048


@pytest.fixture(scope="module")
def us101() -> pl.DataFrame:
    return simulate_recording(US101, 1.0, seed=3)


@pytest.fixture(scope="module")
def i80() -> pl.DataFrame:
    return simulate_recording(I80, 0.5, seed=3)


@pytest.fixture(params=["us101", "i80"])
def rows(request: pytest.FixtureRequest) -> pl.DataFrame:
    return request.getfixturevalue(request.param)


def test_schema_sort_and_frames(rows: pl.DataFrame) -> None:
    assert rows.schema == ns.RAW_SCHEMA
    assert rows.equals(rows.sort(schema.VEHICLE_ID, schema.FRAME_ID))
    assert rows[schema.FRAME_ID].min() == 0
    assert rows[schema.FRAME_ID].max() in (299, 599)
    assert rows.null_count().sum_horizontal().item() == 0


@pytest.mark.slow
def test_same_seed_same_rows_other_seed_other_rows() -> None:
    first = simulate_recording(I80, 0.1, seed=7)
    assert first.equals(simulate_recording(I80, 0.1, seed=7))
    assert not first.equals(simulate_recording(I80, 0.1, seed=8))


def test_unknown_location_is_refused() -> None:
    with pytest.raises(ValueError, match="peachtree"):
        simulate_recording(Recording("peachtree", "0400-0415", 0), 0.1, seed=0)


def test_global_time_is_frame0_plus_frame(rows: pl.DataFrame) -> None:
    frame0 = rows.select(pl.col(schema.GLOBAL_TIME) - 100 * pl.col(schema.FRAME_ID)).to_series()
    assert frame0.n_unique() == 1
    start = US101.start_epoch_ms if rows[schema.LANE_ID].max() == 6 else I80.start_epoch_ms
    assert start - 30_000 <= frame0[0] <= start
    assert frame0[0] % 100 == 0


def test_frames_contiguous_and_total_frames(rows: pl.DataFrame) -> None:
    spans = rows.group_by(schema.VEHICLE_ID).agg(
        pl.len().alias("n"),
        (pl.col(schema.FRAME_ID).max() - pl.col(schema.FRAME_ID).min() + 1).alias("span"),
        pl.col(ns.TOTAL_FRAMES).unique().alias("total"),
    )
    assert (spans["n"] == spans["span"]).all()
    assert (spans["total"].list.len() == 1).all()
    assert (spans["total"].list.first() == spans["n"]).all()


def test_vehicle_ids_dense_in_order_of_entry(rows: pl.DataFrame) -> None:
    first = (
        rows.group_by(schema.VEHICLE_ID).agg(pl.col(schema.FRAME_ID).min()).sort(schema.VEHICLE_ID)
    )
    assert first[schema.VEHICLE_ID].to_list() == list(range(1, len(first) + 1))
    assert first[schema.FRAME_ID].is_sorted()


def test_preceding_and_following_agree(rows: pl.DataFrame) -> None:
    leaders = rows.select(
        pl.col(schema.VEHICLE_ID).alias(schema.PRECEDING),
        schema.FRAME_ID,
        pl.col(schema.LANE_ID).alias("lead_lane"),
        pl.col(ns.LOCAL_Y).alias("lead_y"),
        pl.col(schema.FOLLOWING).alias("lead_following"),
    )
    pairs = rows.filter(pl.col(schema.PRECEDING) != 0).join(
        leaders, on=[schema.PRECEDING, schema.FRAME_ID], how="left"
    )
    assert len(pairs) > 1000
    assert pairs["lead_lane"].null_count() == 0  # the leader is in view at that frame
    assert (pairs[schema.LANE_ID] == pairs["lead_lane"]).all()
    assert (pairs["lead_y"] >= pairs[ns.LOCAL_Y]).all()
    assert (pairs["lead_following"] == pairs[schema.VEHICLE_ID]).all()
    expected = (pairs["lead_y"] - pairs[ns.LOCAL_Y]).round(2)
    assert ((pairs[ns.SPACE_HEADWAY] - expected).abs() < 0.011).all()


def test_following_is_the_nearest_behind_in_lane(rows: pl.DataFrame) -> None:
    frame = rows.filter(pl.col(schema.FRAME_ID) == 100).sort(schema.LANE_ID, ns.LOCAL_Y)
    for lane in frame.partition_by(schema.LANE_ID):
        ids = lane[schema.VEHICLE_ID].to_list()
        assert lane[schema.FOLLOWING].to_list() == [0, *ids[:-1]]
        assert lane[schema.PRECEDING].to_list() == [*ids[1:], 0]


def test_headway_sentinels(rows: pl.DataFrame) -> None:
    alone = rows.filter(pl.col(schema.PRECEDING) == 0)
    assert len(alone) > 0
    assert (alone[ns.SPACE_HEADWAY] == 0).all()
    assert (alone[ns.TIME_HEADWAY] == ns.NO_LEADER_TIME_HEADWAY_S).all()
    led = rows.filter(pl.col(schema.PRECEDING) != 0)
    stopped = led.filter(pl.col(ns.V_VEL) == 0)
    assert (stopped[ns.TIME_HEADWAY] == ns.NO_LEADER_TIME_HEADWAY_S).all()
    moving = led.filter(pl.col(ns.V_VEL) > 1)
    expected = (moving[ns.SPACE_HEADWAY] / moving[ns.V_VEL]).clip(upper_bound=9999.99)
    assert ((moving[ns.TIME_HEADWAY] - expected).abs() < 0.02).all()


def test_speeds_and_accelerations_plausible(rows: pl.DataFrame) -> None:
    speed = rows[ns.V_VEL]
    assert speed.min() >= 0.0
    assert speed.max() <= MAX_SPEED_FPS
    assert rows[ns.V_ACC].abs().max() < 40.0
    # v_Acc is as noisy as NGSIM's: about 9 % of the rows beyond 3 m/s² (raw US-101: 8.99 %).
    hard = (rows[ns.V_ACC].abs() > 3.0 / 0.3048).mean()
    assert 0.06 < hard < 0.13


def test_congested_recordings_are_slower() -> None:
    early = simulate_recording(OFFICIAL_RECORDINGS[1], 0.2, seed=1)  # i-80 0400-0415
    late = simulate_recording(OFFICIAL_RECORDINGS[5], 0.2, seed=1)  # i-80 0515-0530
    assert early[ns.V_VEL].mean() > 1.5 * late[ns.V_VEL].mean()
    assert (late[ns.V_VEL] < 3.0).any()  # stop-and-go
    assert early[ns.V_VEL].quantile(0.95) > 60.0  # about free flow


def test_lanes_positions_and_lane_changes(rows: pl.DataFrame) -> None:
    lanes = 6 if rows[schema.LANE_ID].max() == 6 else 7
    assert rows[schema.LANE_ID].min() == 1
    assert rows[schema.LANE_ID].max() == lanes
    from_x = (rows[ns.LOCAL_X] // 12).cast(pl.Int16) + 1
    assert (from_x == rows[schema.LANE_ID]).all()  # Lane_ID is where the front centre is
    changes = rows.select(
        (pl.col(schema.LANE_ID).diff().over(schema.VEHICLE_ID).fill_null(0) != 0).sum()
    ).item()
    assert changes >= 5


def test_jitter_is_a_few_hundredths_of_a_foot_per_frame(rows: pl.DataFrame) -> None:
    # From one frame to the next Local_X's error changes by its white part's sqrt(2) * 0.04 ft and
    # its correlated part's sqrt(2 (1 - exp(-0.1 / 5))) * 0.12 = 0.024 ft: 0.061 ft in all, whose
    # median absolute value is 0.6745 * 0.061 = 0.041 ft; lane changes add a little.
    steps = rows.select(pl.col(ns.LOCAL_X).diff().over(schema.VEHICLE_ID).abs()).to_series()
    assert 0.03 < steps.median() < 0.08


def test_entries_and_exits_us101(us101: pl.DataFrame) -> None:
    road = ROADWAYS["us-101"]
    spans = us101.group_by(schema.VEHICLE_ID).agg(
        pl.col(schema.FRAME_ID).min().alias("first_frame"),
        pl.col(schema.FRAME_ID).max().alias("last_frame"),
        pl.col(ns.LOCAL_Y).first().alias("first_y"),
        pl.col(ns.LOCAL_Y).last().alias("last_y"),
        pl.col(schema.LANE_ID).first().alias("first_lane"),
        pl.col(schema.LANE_ID).last().alias("last_lane"),
    )
    entered = spans.filter(pl.col("first_frame") > 0)
    assert (entered.filter(pl.col("first_y") < 20)).height > 20  # at the upstream end
    ramp_start = road.extra_lane_ft[0]
    near_ramp = (pl.col("first_y") - ramp_start).abs() < 20
    ramp = entered.filter((pl.col("first_lane") == 6) & near_ramp)
    assert ramp.height >= 1  # at the on-ramp
    left = spans.filter(pl.col("last_frame") < 599)
    assert left.filter(pl.col("last_y") > road.length_ft - 20).height > 20  # at the downstream end
    off_ramp = left.filter((pl.col("last_lane") == 6) & (pl.col("last_y") < road.length_ft - 100))
    assert off_ramp.height >= 1  # at the off-ramp


def test_density_sizes_and_classes(rows: pl.DataFrame) -> None:
    in_view = rows.group_by(schema.FRAME_ID).len()["len"]
    assert 70 < in_view.mean() < 320
    sizes = rows.group_by(schema.V_CLASS).agg(pl.col(ns.V_LENGTH).mean(), pl.len())
    by_class = {row[0]: row[1] for row in sizes.iter_rows()}
    assert set(by_class) <= {1, 2, 3} and 2 in by_class
    assert 13.0 < by_class[2] < 18.0
    assert by_class.get(3, 40.0) > 25.0


def test_global_coordinates_rotate_local_ones(us101: pl.DataFrame) -> None:
    assert 6_440_000 < us101[ns.GLOBAL_X].mean() < 6_460_000
    assert 1_860_000 < us101[ns.GLOBAL_Y].mean() < 1_880_000
    a, b = us101.row(0, named=True), us101.row(len(us101) // 2, named=True)
    local = np.hypot(a["local_x"] - b["local_x"], a["local_y"] - b["local_y"])
    world = np.hypot(a["global_x"] - b["global_x"], a["global_y"] - b["global_y"])
    assert abs(local - world) < 0.01


def test_ngsim_rounding(rows: pl.DataFrame) -> None:
    for name, decimals in ((ns.LOCAL_X, 3), (ns.GLOBAL_Y, 3), (ns.V_LENGTH, 1),
                           (ns.V_VEL, 2), (ns.TIME_HEADWAY, 2)):  # fmt: skip
        assert (rows[name] - rows[name].round(decimals)).abs().max() < 1e-9
