"""The synthetic road sections and the traffic each recording puts on them (NGSIM units: feet, s).

A section is straight. Local_Y runs along the direction of travel from 0 at the upstream edge of the
camera view to `length_ft` at the downstream edge; Local_X runs to the right, lane 1 being the
leftmost, with lane centres at (lane - 0.5) * 12 ft. The simulation extends the road before the view
(where entering traffic settles) and after it (where the bottleneck that queues traffic into the view
lies). Global coordinates are a rotation and offset of the local ones into state-plane-like feet.
"""

from __future__ import annotations

from dataclasses import dataclass

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
    ("us-101", "0750am-0805am"): Regime(1650.0, 500.0, 0.25, 65.0, (75.0, 40.0), 14.0, 150.0),
    ("us-101", "0805am-0820am"): Regime(1750.0, 550.0, 0.25, 42.0, (46.0, 38.0), 16.0, 170.0),
    ("us-101", "0820am-0835am"): Regime(1800.0, 600.0, 0.25, 36.0, (40.0, 34.0), 18.0, 190.0),
    ("i-80", "0400-0415"): Regime(1700.0, 450.0, 0.0, 70.0, (90.0, 26.0), 14.0, 160.0),
    ("i-80", "0500-0515"): Regime(1750.0, 550.0, 0.0, 28.0, (30.0, 26.0), 16.0, 180.0),
    ("i-80", "0515-0530"): Regime(1750.0, 550.0, 0.0, 25.0, (27.0, 24.0), 16.0, 200.0),
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


def to_global_ft(
    local_x_ft: np.ndarray, local_y_ft: np.ndarray, roadway: Roadway
) -> tuple[np.ndarray, np.ndarray]:
    """(Global_X, Global_Y) in feet of local positions (N,): travel along the heading, x to its right."""
    sin_h, cos_h = np.sin(roadway.heading_rad), np.cos(roadway.heading_rad)
    global_x = roadway.origin_ft[0] + local_y_ft * sin_h + local_x_ft * cos_h
    global_y = roadway.origin_ft[1] + local_y_ft * cos_h - local_x_ft * sin_h
    return global_x, global_y


def bottleneck_cap_fps(regime: Regime, t_s: float, duration_s: float, phase_rad: float) -> float:
    """The bottleneck's speed cap (ft/s) at time t_s of a recording lasting duration_s (>= 3 ft/s)."""
    progress = min(max(t_s / max(duration_s, 1.0), 0.0), 1.0)
    start, end = regime.bottleneck_fps
    wave = regime.wave_amplitude_fps * np.sin(2 * np.pi * t_s / regime.wave_period_s + phase_rad)
    return max(start + (end - start) * progress + wave, 3.0)
