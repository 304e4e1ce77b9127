"""A seeded microscopic traffic simulation of one recording, observed the way NGSIM's video was.

The drivers follow the improved Intelligent Driver Model and change lanes by MOBIL, with biases
for mandatory moves (`drivers`, `road.change_bias`). A downstream bottleneck whose speed cap
varies in time queues the traffic into the view and sends stop-and-go waves upstream. Every step
is vectorised over the vehicles; the loop runs over time only. Units are NGSIM's: feet, seconds,
feet/s, feet/s^2.

The fleet is a numpy structured array, one row per simulated vehicle, appended on entry and removed
on exit. A vehicle changing lanes (`from_lane != lane`) follows leaders in both lanes and is a
leader in both until it is half-way across (`drivers.LEFT_OLD_LANE`).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np
import polars as pl

from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS, Recording
from ngsim_graphs.synth.camera import Sightings, observed_rows
from ngsim_graphs.synth.drivers import (
    RELAX_S,
    LaneIndex,
    accelerations,
    change_gain,
    gap_to,
    lane_index,
    neighbours_at,
    relax,
)
from ngsim_graphs.synth.road import (
    ROADWAYS,
    EntryPoints,
    Regime,
    Roadway,
    bottleneck_cap_fps,
    entry_points,
    lane_centre_ft,
    regime_for,
)

DT_S = 0.1  # one NGSIM frame
WARMUP_S = 150.0  # simulated before frame 0, so the recording opens on settled traffic
MAX_BRAKE_FPS2 = 30.0  # about 0.9 g
DECISION_EVERY = 5  # steps between two lane-change decisions of one driver (0.5 s)
CHANGE_THRESHOLD_FPS2 = 0.1  # advantage a discretionary lane change must bring
COOLDOWN_S = 4.0  # after the start of one lane change, before the next decision
# A lateral move follows a path along the lane: it takes at least a few seconds (its own, drawn
# in CHANGE_MIN_S) and, at a speed v, at least the path's length / v, so that its angle to the
# lane stays a few degrees (NGSIM's headings are small); but no more than CHANGE_MAX_S, by which a
# driver crawling in a queue has squeezed in all the same, at a steeper angle.
CHANGE_MIN_S = (3.0, 5.0)
CHANGE_LENGTH_FT = (180.0, 300.0)  # about 55 to 90 m
CHANGE_MAX_S = 20.0
RELAX_DECAY = np.exp(-DT_S / RELAX_S)  # per step, of a relaxed driver's shortened headway
ENTRY_GAP_FT, ENTRY_HEADWAY_S = 7.0, 1.2  # room a vehicle needs to enter at speed v
MAX_PENDING = 20  # vehicles waiting to enter at one entry point

FLEET_DTYPE = np.dtype(
    [
        ("uid", np.int64),  # creation order, dense from 0
        ("y", np.float64),  # front position, ft
        ("v", np.float64),  # ft/s
        ("acc", np.float64),  # over the last step, ft/s^2
        ("lane", np.int16),  # lane it drives in, or moves to
        ("from_lane", np.int16),  # lane it leaves while changing, else == lane
        ("change_s", np.float64),  # time since the lane change began
        ("change_frac", np.float64),  # progress of the lateral move, 0 to 1
        ("change_min_s", np.float64),  # shortest duration of the lateral move
        ("change_len_ft", np.float64),  # length of its path along the lane
        ("offset_x", np.float64),  # preferred lateral offset from the lane centre, ft
        ("v0", np.float64),  # IDM desired speed, ft/s
        ("headway_s", np.float64),  # IDM safe time headway
        ("relax_s", np.float64),  # by how much it is shortened for now (relaxation)
        ("a_max", np.float64),  # IDM maximum acceleration, ft/s^2
        ("b_comf", np.float64),  # IDM comfortable deceleration, ft/s^2
        ("s0", np.float64),  # IDM jam distance, ft
        ("length", np.float64),
        ("width", np.float64),
        ("v_class", np.int8),  # 1 motorcycle, 2 auto, 3 truck
        ("exits", np.bool_),  # bound for the off-ramp
        ("noise_x", np.float64),  # temporally correlated measurement error, ft
        ("noise_y", np.float64),
        ("noise_a", np.float64),  # driver's acceleration noise, ft/s^2
        ("noise_v", np.float64),  # error of the recorded speed (v_Vel), ft/s
        ("noise_v_raw", np.float64),  # what noise_v smooths
        ("noise_acc", np.float64),  # error of the recorded acceleration (v_Acc), ft/s^2
    ]
)
# The error of the recorded speed is smooth: a first-order autoregressive process (noise_v_raw)
# seen through a first-order low-pass filter of SPEED_SMOOTHING_S, as a speed estimated over a few
# frames is. Its standard deviation after the filter is SPEED_ERROR_SD_FPS (constant velocity's
# error at 1 s needs it that large); unfiltered, it would give the jerk (the speed's second
# difference) about twice the scatter of real US-101 data (docs/synthetic.md).
SPEED_ERROR_SD_FPS = 2.45
SPEED_ERROR_TAU_S = 0.5
SPEED_SMOOTHING_S = 0.3
_SMOOTH = np.exp(-DT_S / SPEED_SMOOTHING_S)
_RHO_V = np.exp(-DT_S / SPEED_ERROR_TAU_S)
# The filter's variance gain on an AR(1) input: (1 - b)(1 + b rho) / ((1 + b)(1 - b rho)).
_GAIN_V = (1 - _SMOOTH) * (1 + _SMOOTH * _RHO_V) / ((1 + _SMOOTH) * (1 - _SMOOTH * _RHO_V))
# Each a first-order autoregressive process per vehicle: its standard deviation and time constant.
NOISES = ("noise_x", "noise_y", "noise_a", "noise_v_raw", "noise_acc")
# ft, ft, ft/s^2, ft/s, ft/s^2
NOISE_SD = np.array([0.12, 0.35, 0.9, SPEED_ERROR_SD_FPS / np.sqrt(_GAIN_V), 5.4])
NOISE_RHO = np.exp(-DT_S / np.array([5.0, 1.0, 2.0, SPEED_ERROR_TAU_S, 0.3]))  # AR(1) factors


@dataclass
class _Simulation:
    """Mutable state of one run: the fleet, the entry queues, the log of every vehicle created."""

    roadway: Roadway
    regime: Regime
    rng: np.random.Generator
    entries: EntryPoints
    pending: np.ndarray  # (P,) vehicles waiting at each entry point
    fleet: np.ndarray = field(default_factory=lambda: np.zeros(0, FLEET_DTYPE))
    created: list[np.ndarray] = field(default_factory=list)
    next_uid: int = 0


def simulate_recording(recording: Recording, minutes: float, seed: int) -> pl.DataFrame:
    """The clean raw rows of one synthetic recording, `ns.RAW_SCHEMA`, NGSIM units.

    Frame_ID runs from 0 at 10 Hz for `minutes`; Global_Time = frame0 + 100 * Frame_ID, frame0 being
    the recording's nominal start minus a seeded 0..30 s. Rows are sorted by (vehicle_id, frame_id).
    Deterministic in (recording, minutes, seed). Raises ValueError for a location without a
    synthetic roadway (see `road.ROADWAYS`).
    """
    if recording.location not in ROADWAYS:
        raise ValueError(f"no synthetic roadway for location {recording.location!r}")
    roadway = ROADWAYS[recording.location]
    rng = np.random.default_rng([seed, _recording_index(recording)])
    frame0_ms = recording.start_epoch_ms - 100 * int(rng.integers(0, 301))
    n_frames = max(1, round(minutes * 60 / DT_S))
    sim = _start(roadway, regime_for(recording.location, recording.period), rng)
    sightings = _run(sim, n_frames)
    return observed_rows(sightings, np.concatenate(sim.created), roadway, frame0_ms, rng)


def _recording_index(recording: Recording) -> int:
    """The recording's place among the official six; a stable number past them for any other."""
    if recording in OFFICIAL_RECORDINGS:
        return OFFICIAL_RECORDINGS.index(recording)
    name = f"{recording.location}/{recording.period}".encode()
    return len(OFFICIAL_RECORDINGS) + zlib.crc32(name)


def _start(roadway: Roadway, regime: Regime, rng: np.random.Generator) -> _Simulation:
    """A simulation whose lanes are filled at the regime's initial speed."""
    entries = entry_points(roadway, regime)
    sim = _Simulation(roadway, regime, rng, entries, np.zeros(roadway.lanes, np.int64))
    for lane in range(1, roadway.lanes + 1):
        _fill_lane(sim, lane)
    return sim


def _fill_lane(sim: _Simulation, lane: int) -> None:
    """Queue vehicles along one lane at the initial speed, downstream end first."""
    roadway, speed = sim.roadway, sim.regime.initial_speed_fps
    start, end = -roadway.upstream_ft, roadway.length_ft + roadway.downstream_ft
    sparse = 1.0
    if lane > roadway.main_lanes:
        start, end = roadway.extra_lane_ft or (start, end)
        end -= 150.0  # leave the lane's end free for merging
        sparse = 2.5
    count = int((end - start) / (22.0 + 1.3 * speed)) + 1
    new = _new_vehicles(sim, count)
    gaps = sparse * (new["s0"] + speed * new["headway_s"]) * sim.rng.uniform(1.0, 1.4, count)
    new["y"] = end - np.concatenate([[0.0], np.cumsum(new["length"][:-1] + gaps[1:])])
    new["v"] = np.minimum(speed, new["v0"])
    new["lane"] = new["from_lane"] = lane
    new["exits"] = sim.rng.random(count) < sim.entries.exit_share[lane - 1]
    sim.fleet = np.concatenate([sim.fleet, new[new["y"] > start]])


def _new_vehicles(sim: _Simulation, n: int) -> np.ndarray:
    """n new vehicles with sampled class, size and driver parameters; logged in `sim.created`."""
    rng, free = sim.rng, sim.roadway.free_speed_fps
    new = np.zeros(n, FLEET_DTYPE)
    u = rng.random(n)
    v_class = np.where(u < 0.006, 1, np.where(u < 0.046, 3, 2)).astype(np.int8)
    moto, truck = v_class == 1, v_class == 3
    long_truck = rng.random(n) < 0.5
    new["length"] = np.where(
        truck,
        np.where(long_truck, rng.uniform(55, 72, n), rng.uniform(26, 40, n)),
        np.where(moto, rng.uniform(6.5, 8.0, n), rng.normal(15.2, 1.9, n).clip(11.5, 21.5)),
    )
    new["width"] = np.where(
        truck,
        rng.uniform(7.8, 8.5, n),
        np.where(moto, rng.uniform(2.5, 3.3, n), rng.normal(6.1, 0.4, n).clip(5.0, 7.5)),
    )
    new["v_class"] = v_class
    new["v0"] = free * rng.normal(1.0, 0.08, n) * np.where(truck, 0.88, np.where(moto, 1.05, 1.0))
    new["headway_s"] = rng.normal(1.35, 0.25, n).clip(0.9, 2.2) + np.where(truck, 0.4, 0.0)
    new["a_max"] = np.where(truck, rng.uniform(1.6, 2.6, n), rng.uniform(3.3, 5.0, n))
    new["b_comf"] = rng.uniform(5.0, 7.0, n)
    new["s0"] = rng.uniform(5.5, 9.0, n)
    new["offset_x"] = rng.normal(0.0, 0.6, n).clip(-1.5, 1.5)
    new["change_frac"] = new["change_min_s"] = new["change_len_ft"] = 1.0
    new["change_s"] = COOLDOWN_S
    for name, value in zip(
        NOISES, rng.normal(0.0, NOISE_SD[:, None], (len(NOISES), n)), strict=True
    ):
        new[name] = value
    new["noise_v"] = rng.normal(0.0, SPEED_ERROR_SD_FPS, n)
    new["uid"] = sim.next_uid + np.arange(n)
    sim.next_uid += n
    sim.created.append(new[["uid", "length", "width", "v_class"]])
    return new


def _run(sim: _Simulation, n_frames: int) -> Sightings:
    """Warm up, then run n_frames steps, recording the vehicles inside the view at every frame."""
    duration_s = n_frames * DT_S
    phase = float(sim.rng.uniform(0, 2 * np.pi))
    blocks: list[np.ndarray] = []
    counts = np.zeros(n_frames, np.int64)
    for step in range(-round(WARMUP_S / DT_S), n_frames):
        cap = bottleneck_cap_fps(sim.regime, step * DT_S, duration_s, phase)
        following, index = lane_index(sim.fleet, sim.roadway)
        acc = accelerations(sim.fleet, following, sim.roadway, cap)
        _change_lanes(sim, index, acc, step)
        _move(sim, acc)
        if step >= 0:
            blocks.append(_in_view(sim.fleet, sim.roadway))
            counts[step] = len(blocks[-1])
        _enter(sim, index)
        _leave(sim)
    columns = np.concatenate(blocks).T  # (10, R)
    frames = np.repeat(np.arange(n_frames, dtype=np.int32), counts)
    return Sightings(columns[0].astype(np.int64), frames, *columns[1:])


def _change_lanes(sim: _Simulation, index: LaneIndex, acc: np.ndarray, step: int) -> None:
    """MOBIL decisions of the drivers whose turn it is; chosen changes start their lateral move."""
    fleet = sim.fleet
    deciding = (
        (fleet["from_lane"] == fleet["lane"])
        & (fleet["change_s"] >= COOLDOWN_S)
        & ((fleet["uid"] + step) % DECISION_EVERY == 0)
        & (fleet["y"] > 100.0 - sim.roadway.upstream_ft)
    )
    rows = np.flatnonzero(deciding)
    if rows.size == 0:
        return
    # One direction per round: two drivers never claim one gap from both sides in the same step.
    direction = -1 if (step // DECISION_EVERY) % 2 == 0 else 1
    lane = fleet["lane"][rows]
    target = (lane + direction).astype(np.int16)
    gain = change_gain(fleet, index, acc, rows, target, sim.roadway)
    moving = rows[gain > CHANGE_THRESHOLD_FPS2]
    relax(fleet, index, moving, (fleet["lane"][moving] + direction).astype(np.int16))
    fleet["from_lane"][moving] = fleet["lane"][moving]
    fleet["lane"][moving] += direction
    fleet["change_s"][moving] = fleet["change_frac"][moving] = 0.0
    fleet["change_min_s"][moving] = sim.rng.uniform(*CHANGE_MIN_S, moving.size)
    fleet["change_len_ft"][moving] = sim.rng.uniform(*CHANGE_LENGTH_FT, moving.size)


def _lateral_ft(fleet: np.ndarray) -> np.ndarray:
    """Noise-free Local_X (N,) ft: lane centre plus offset, eased across a lane change."""
    frac = np.clip(fleet["change_frac"], 0.0, 1.0)
    ease = frac * frac * (3.0 - 2.0 * frac)
    start, goal = lane_centre_ft(fleet["from_lane"]), lane_centre_ft(fleet["lane"])
    return start + (goal - start) * ease + fleet["offset_x"]


def _move(sim: _Simulation, acc: np.ndarray) -> None:
    """Advance one step: speeds (never negative), positions, lane-change progress, noise states."""
    fleet, n = sim.fleet, len(sim.fleet)
    acc = np.clip(acc + fleet["noise_a"], -MAX_BRAKE_FPS2, fleet["a_max"] * 1.2)
    v_old = fleet["v"].copy()
    v_new = np.maximum(v_old + acc * DT_S, 0.0)
    fleet["y"] += 0.5 * (v_old + v_new) * DT_S
    fleet["v"] = v_new
    fleet["acc"] = (v_new - v_old) / DT_S
    fleet["change_s"] += DT_S
    fleet["relax_s"] *= RELAX_DECAY
    rate = np.clip(v_new / fleet["change_len_ft"], 1.0 / CHANGE_MAX_S, 1.0 / fleet["change_min_s"])
    fleet["change_frac"] += rate * DT_S
    done = (fleet["from_lane"] != fleet["lane"]) & (fleet["change_frac"] >= 1.0)
    fleet["from_lane"][done] = fleet["lane"][done]
    shocks = sim.rng.standard_normal((len(NOISES), n))
    shocks *= (NOISE_SD * np.sqrt(1 - NOISE_RHO**2))[:, None]
    for k, name in enumerate(NOISES):
        fleet[name] = NOISE_RHO[k] * fleet[name] + shocks[k]
    fleet["noise_v"] = _SMOOTH * fleet["noise_v"] + (1 - _SMOOTH) * fleet["noise_v_raw"]


def _in_view(fleet: np.ndarray, roadway: Roadway) -> np.ndarray:
    """(K, 10) uid, y, x, v, acc and the measurement errors of the vehicles in the view (see
    Sightings)."""
    # A foot of margin at the edges keeps the jittered Local_Y inside [0, length].
    inside = (fleet["y"] >= 1.0) & (fleet["y"] <= roadway.length_ft - 1.0)
    seen = fleet[inside]
    columns = (
        seen["uid"],
        seen["y"],
        _lateral_ft(seen),
        seen["v"],
        seen["acc"],
        seen["noise_x"],
        seen["noise_y"],
        seen["noise_v"],
        seen["noise_acc"],
    )
    return np.column_stack(columns).astype(np.float64)


def _enter(sim: _Simulation, index: LaneIndex) -> None:
    """Arrivals join the entry queues; the head of each queue enters when its lane has room."""
    entries = sim.entries
    sim.pending = np.minimum(sim.pending + sim.rng.poisson(entries.rate_per_s * DT_S), MAX_PENDING)
    points = np.flatnonzero(sim.pending > 0)
    if points.size == 0:
        return
    lanes, ys = entries.lane[points], entries.y_ft[points]
    leader, _ = neighbours_at(index, lanes, ys)
    free = sim.roadway.free_speed_fps * np.where(lanes > sim.roadway.main_lanes, 0.7, 0.95)
    gap, v_lead = np.full(points.size, np.inf), free
    if len(sim.fleet):
        gap, v_lead = gap_to(sim.fleet, np.zeros_like(leader), leader, ys)
    v_in = np.where(leader >= 0, np.minimum(v_lead, free), free)
    fits = gap >= ENTRY_GAP_FT + ENTRY_HEADWAY_S * v_in
    if not fits.any():
        return
    entering = points[fits]
    new = _new_vehicles(sim, entering.size)
    new["y"] = ys[fits]
    new["lane"] = new["from_lane"] = lanes[fits]
    new["v"] = np.minimum(v_in[fits], new["v0"])
    new["exits"] = sim.rng.random(entering.size) < entries.exit_share[entering]
    sim.pending[entering] -= 1
    sim.fleet = np.concatenate([sim.fleet, new])


def _leave(sim: _Simulation) -> None:
    """Remove vehicles past the simulated road and those taking the off-ramp."""
    fleet, roadway = sim.fleet, sim.roadway
    gone = fleet["y"] > roadway.length_ft + roadway.downstream_ft
    if roadway.extra_lane_ft is not None and roadway.extra_lane_exits:
        end = roadway.extra_lane_ft[1]
        gone |= fleet["exits"] & (fleet["lane"] == roadway.lanes) & (fleet["y"] >= end)
        fleet["exits"] &= fleet["y"] < end  # those who missed it drive on
    if gone.any():
        sim.fleet = fleet[~gone]
