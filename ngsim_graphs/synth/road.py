"""The synthetic road sections: geometry, the traffic each recording puts on them, and the rules of
the road (where traffic enters, which lane changes are allowed or mandatory). NGSIM units: feet,
seconds; `camera` records the vehicles on them as NGSIM rows.

A section is straight. Local_Y runs along the direction of travel from 0 at the upstream edge of the
camera view to `length_ft` at the downstream edge; Local_X runs to the right, lane 1 being the
leftmost, with lane centres at (lane - 0.5) * 12 ft. The simulation extends the road before the view
(where entering traffic settles) and after it (where lies the bottleneck that queues traffic into
the view).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

LANE_WIDTH_FT = 12.0


@dataclass(frozen=True)
class Roadway:
    """One section's geometry. Lane `main_lanes + 1`, if any, is the auxiliary or merge lane."""

    main_lanes: int
    length_ft: float  # the camera view, Local_Y in [0, length_ft]
    extra_lane_ft: tuple[float, float] | None  # (start, end) Local_Y of the extra lane
    extra_lane_exits: bool  # True: an off-ramp leaves at its end; False: it ends in a merge
    free_speed_fps: float  # mean desired speed of cars
    origin_ft: tuple[float, float]  # (Global_X, Global_Y) of Local (0, 0)
    heading_rad: float  # direction of travel, clockwise from the Global_Y axis
    upstream_ft: float = 600.0  # simulated road before the view
    downstream_ft: float = 1200.0  # simulated road after the view
    bottleneck_ft: tuple[float, float] = (300.0, 800.0)  # past the view's downstream edge

    @property
    def lanes(self) -> int:
        """Lanes in all, the extra lane included."""
        return self.main_lanes + (self.extra_lane_ft is not None)


@dataclass(frozen=True)
class Regime:
    """The traffic of one recording: demand and the time-varying bottleneck that queues it.

    The bottleneck caps desired speeds at `bottleneck_fps[0]` at frame 0, moving linearly to
    `bottleneck_fps[1]` at the last frame, plus a sinusoid of `wave_amplitude_fps` whose troughs
    send stop-and-go waves upstream through the view.
    """

    demand_vph_per_lane: float  # arrivals at the upstream end, per main lane
    ramp_vph: float  # arrivals at the start of the extra lane
    exit_share: float  # share of right-lane and ramp vehicles bound for the off-ramp
    initial_speed_fps: float  # speed of the traffic the simulation starts from
    bottleneck_fps: tuple[float, float]
    wave_amplitude_fps: float
    wave_period_s: float


ROADWAYS: dict[str, Roadway] = {
    # Hollywood Freeway southbound near Lankershim: 5 lanes, an auxiliary lane from the Ventura
    # on-ramp to the Cahuenga off-ramp.
    "us-101": Roadway(
        main_lanes=5,
        length_ft=2100.0,
        extra_lane_ft=(250.0, 1850.0),
        extra_lane_exits=True,
        free_speed_fps=96.0,
        origin_ft=(6452300.0, 1871600.0),
        heading_rad=np.deg2rad(-28.0),
    ),
    # I-80 eastbound in Emeryville: 6 lanes and the Powell Street on-ramp merge lane.
    "i-80": Roadway(
        main_lanes=6,
        length_ft=1650.0,
        extra_lane_ft=(-300.0, 650.0),
        extra_lane_exits=False,
        free_speed_fps=94.0,
        origin_ft=(6042600.0, 2132900.0),
        heading_rad=np.deg2rad(-6.0),
    ),
    # An arterial, only for the foreign-location rows of the portal quirks.
    "lankershim": Roadway(
        main_lanes=3,
        length_ft=1600.0,
        extra_lane_ft=None,
        extra_lane_exits=False,
        free_speed_fps=55.0,
        origin_ft=(6451900.0, 1872700.0),
        heading_rad=np.deg2rad(-20.0),
    ),
}

# Later periods are more congested, as in the real data (I-80 after 5 pm is stop-and-go).
REGIMES: dict[tuple[str, str], Regime] = {
    ("us-101", "0750am-0805am"): Regime(1750.0, 450.0, 0.2, 70.0, (75.0, 32.0), 15.0, 150.0),
    ("us-101", "0805am-0820am"): Regime(1800.0, 450.0, 0.2, 38.0, (40.0, 30.0), 15.0, 170.0),
    ("us-101", "0820am-0835am"): Regime(1850.0, 450.0, 0.2, 32.0, (34.0, 28.0), 15.0, 190.0),
    ("i-80", "0400-0415"): Regime(1800.0, 450.0, 0.0, 75.0, (50.0, 22.0), 14.0, 160.0),
    ("i-80", "0500-0515"): Regime(1800.0, 550.0, 0.0, 22.0, (24.0, 20.0), 12.0, 180.0),
    ("i-80", "0515-0530"): Regime(1800.0, 550.0, 0.0, 20.0, (22.0, 18.0), 12.0, 200.0),
}
DEFAULT_REGIME = Regime(1000.0, 0.0, 0.0, 30.0, (35.0, 35.0), 8.0, 120.0)


def regime_for(location: str, period: str) -> Regime:
    """The traffic regime of a recording; a moderate default for recordings not in the table."""
    return REGIMES.get((location, period), DEFAULT_REGIME)


def lane_centre_ft(lane: np.ndarray) -> np.ndarray:
    """Local_X (ft) of the centre of each lane number (1 = leftmost), any shape."""
    return (lane - 0.5) * LANE_WIDTH_FT


def lane_of_ft(local_x_ft: np.ndarray, roadway: Roadway) -> np.ndarray:
    """Lane number (int16) containing each lateral position, clipped to the section's lanes."""
    lane = np.floor(local_x_ft / LANE_WIDTH_FT).astype(np.int16) + 1
    return np.clip(lane, 1, roadway.lanes).astype(np.int16)


def bottleneck_cap_fps(regime: Regime, t_s: float, duration_s: float, phase_rad: float) -> float:
    """The bottleneck's speed cap (ft/s, at least 3) at time t_s of a recording of duration_s."""
    progress = min(max(t_s / max(duration_s, 1.0), 0.0), 1.0)
    start, end = regime.bottleneck_fps
    wave = regime.wave_amplitude_fps * np.sin(2 * np.pi * t_s / regime.wave_period_s + phase_rad)
    return max(start + (end - start) * progress + wave, 3.0)


class EntryPoints(NamedTuple):
    """Where traffic enters, one point per lane (P = roadway.lanes): arrays (P,)."""

    lane: np.ndarray
    y_ft: np.ndarray  # the upstream end of the simulated road, or the start of the extra lane
    rate_per_s: np.ndarray  # mean arrivals per second (Poisson)
    exit_share: np.ndarray  # chance that a vehicle entering there is bound for the off-ramp


def entry_points(roadway: Roadway, regime: Regime) -> EntryPoints:
    """Mainline entries at the upstream end of every main lane, the on-ramp at the extra lane."""
    lane = np.arange(1, roadway.lanes + 1, dtype=np.int16)
    main = lane <= roadway.main_lanes
    ramp_start = roadway.extra_lane_ft[0] if roadway.extra_lane_ft else 0.0
    rate_vph = np.where(main, regime.demand_vph_per_lane, regime.ramp_vph)
    # Off-ramp traffic comes from the right-hand lanes and the on-ramp.
    share = np.where(lane >= roadway.main_lanes - 1, regime.exit_share, 0.0)
    return EntryPoints(
        lane,
        np.where(main, -roadway.upstream_ft, ramp_start),
        rate_vph / 3600.0,
        share if roadway.extra_lane_exits else np.zeros(roadway.lanes),
    )


def lane_open(
    roadway: Roadway, target: np.ndarray, y_ft: np.ndarray, exits: np.ndarray
) -> np.ndarray:
    """Whether vehicles at y_ft (N,) may move into target lanes (N,): the lane exists there and,
    for an auxiliary lane, the vehicle is not too close to its end. Nobody enters a merge lane."""
    is_open = (target >= 1) & (target <= roadway.main_lanes)
    if roadway.extra_lane_ft is not None and roadway.extra_lane_exits:
        start, end = roadway.extra_lane_ft
        room = np.where(exits, 60.0, 500.0)  # through traffic only uses it well before its end
        is_open |= (target == roadway.lanes) & (y_ft > start + 50.0) & (y_ft < end - room)
    return is_open


def change_bias(
    roadway: Roadway, lane: np.ndarray, target: np.ndarray, y_ft: np.ndarray, exits: np.ndarray
) -> np.ndarray:
    """Extra lane-change incentive (ft/s^2, (N,)) for mandatory moves: out of the extra lane
    before it ends, towards the off-ramp before it leaves; both grow as the point nears."""
    bias = np.zeros(len(lane))
    if roadway.extra_lane_ft is None:
        return bias
    start, end = roadway.extra_lane_ft
    direction = target - lane
    exiting = exits & roadway.extra_lane_exits & (y_ft < end)
    through_in_extra = (lane == roadway.lanes) & ~exiting
    urgency_end = np.clip((y_ft - start) / (end - start - 100.0), 0.0, 1.0)
    bias += np.where(through_in_extra & (direction == -1), 2.0 + 8.0 * urgency_end**2, 0.0)
    bias += np.where((target == roadway.lanes) & ~exiting, -1.5, 0.0)
    urgency_exit = np.clip((y_ft - (end - 1500.0)) / 1200.0, 0.0, 1.0)
    bias += np.where(exiting, direction * (0.5 + 6.0 * urgency_exit), 0.0)
    return bias
