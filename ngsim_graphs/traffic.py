"""A seeded microscopic traffic simulation of one recording, observed the way NGSIM's video was.

Car-following is the Intelligent Driver Model (Treiber, Hennecke, Helbing 2000), lane changes are
MOBIL (Kesting, Treiber, Helbing 2007) with biases for mandatory moves (merging out of an ending
lane, reaching the off-ramp). A downstream bottleneck whose speed cap varies in time queues the
traffic into the view and sends stop-and-go waves upstream. Every step is vectorised over the
vehicles; the loop runs over time only. Units are NGSIM's: feet, seconds, feet/s, feet/s^2.

The fleet is a numpy structured array, one row per simulated vehicle, rows appended on entry and
removed on exit. A vehicle changing lanes (`from_lane != lane`) follows leaders in both lanes and
is a leader in both, until its lateral move ends.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import polars as pl

from ngsim_graphs import schema
from ngsim_graphs.recordings import OFFICIAL_RECORDINGS, Recording
from ngsim_graphs.roadway import (
    ROADWAYS,
    Regime,
    Roadway,
    bottleneck_cap_fps,
    lane_centre_ft,
    lane_of_ft,
    regime_for,
    to_global_ft,
)

DT_S = 0.1  # one NGSIM frame
WARMUP_S = 150.0  # simulated before frame 0, so the recording opens on settled traffic
MAX_BRAKE_FPS2 = 30.0  # about 0.9 g
KEY_LANE = 1.0e5  # sort key lane * KEY_LANE + y + KEY_OFFSET orders entries by lane, then y
KEY_OFFSET = 1.0e4
DECISION_EVERY = 10  # steps between two lane-change decisions of one driver (1 s)
POLITENESS = 0.3  # MOBIL's weight of the new follower's disadvantage
CHANGE_THRESHOLD_FPS2 = 0.8  # advantage a discretionary lane change must bring
SAFE_BRAKE_FPS2 = 12.0  # MOBIL safety: the new follower need not brake harder than this
COOLDOWN_S = 6.0  # after the start of one lane change, before the next decision
MIN_GAP_FT = 3.0
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
        ("change_dur_s", np.float64),
        ("offset_x", np.float64),  # preferred lateral offset from the lane centre, ft
        ("v0", np.float64),  # IDM desired speed, ft/s
        ("headway_s", np.float64),  # IDM safe time headway
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
    ]
)
NOISE_SD = np.array([0.25, 0.35, 0.6])  # noise_x ft, noise_y ft, noise_a ft/s^2
NOISE_RHO = np.exp(-DT_S / np.array([1.0, 1.0, 2.0]))  # AR(1) factors, time constants in s


class _LaneIndex(NamedTuple):
    """Lane occupancy: (E,) entries sorted by lane then y; a changing vehicle has two entries."""

    keys: np.ndarray
    vehicle: np.ndarray  # fleet row of each entry
    lane: np.ndarray


@dataclass
class _Simulation:
    """Mutable state of one run: the fleet, the entry queues and the log of every vehicle created."""

    roadway: Roadway
    regime: Regime
    rng: np.random.Generator
    fleet: np.ndarray
    entry_lane: np.ndarray  # (P,) entry points: lane, Local_Y, rate (veh/s), off-ramp share
    entry_y: np.ndarray
    entry_rate: np.ndarray
    entry_exit_share: np.ndarray
    pending: np.ndarray  # (P,) vehicles waiting at each entry point
    created: list[np.ndarray] = field(default_factory=list)
    next_uid: int = 0


def simulate_recording(recording: Recording, minutes: float, seed: int) -> pl.DataFrame:
    """The clean raw rows of one synthetic recording, `schema.RAW_SCHEMA`, NGSIM units.

    Frame_ID runs from 0 at 10 Hz for `minutes`; Global_Time = frame0 + 100 * Frame_ID, frame0 being
    the recording's nominal start minus a seeded 0..30 s. Rows are sorted by (vehicle_id, frame_id).
    Deterministic in (recording, minutes, seed).
    """
    roadway = ROADWAYS[recording.location]
    rng = np.random.default_rng([seed, _recording_index(recording)])
    frame0_ms = recording.start_epoch_ms - 100 * int(rng.integers(0, 301))
    n_frames = max(1, round(minutes * 60 / DT_S))
    sim = _start(roadway, regime_for(recording.location, recording.period), rng)
    observed, frames = _run(sim, n_frames)
    static = np.concatenate(sim.created)
    return _observe_rows(observed, frames, static, roadway, frame0_ms, rng)


def _recording_index(recording: Recording) -> int:
    if recording in OFFICIAL_RECORDINGS:
        return OFFICIAL_RECORDINGS.index(recording)
    return len(OFFICIAL_RECORDINGS) + zlib.crc32(f"{recording.location}/{recording.period}".encode())


def _start(roadway: Roadway, regime: Regime, rng: np.random.Generator) -> _Simulation:
    """A simulation whose road is filled at the regime's initial speed, with its entry points."""
    lanes = list(range(1, roadway.main_lanes + 1))
    ys = [-roadway.upstream_ft] * roadway.main_lanes
    rates = [regime.demand_vph_per_lane / 3600.0] * roadway.main_lanes
    ramp_share = regime.exit_share if roadway.extra_lane_exits else 0.0
    shares = [ramp_share if lane >= roadway.main_lanes - 1 else 0.0 for lane in lanes]
    if roadway.extra_lane_ft is not None:
        lanes.append(roadway.lanes)
        ys.append(roadway.extra_lane_ft[0])
        rates.append(regime.ramp_vph / 3600.0)
        shares.append(ramp_share)
    sim = _Simulation(
        roadway, regime, rng, np.zeros(0, FLEET_DTYPE), np.array(lanes, np.int16),
        np.array(ys), np.array(rates), np.array(shares), np.zeros(len(lanes), np.int64),
    )  # fmt: skip
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
    share = sim.entry_exit_share[min(lane, len(sim.entry_exit_share)) - 1]
    new["exits"] = sim.rng.random(count) < share
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
        truck, rng.uniform(7.8, 8.5, n),
        np.where(moto, rng.uniform(2.5, 3.3, n), rng.normal(6.1, 0.4, n).clip(5.0, 7.5)),
    )  # fmt: skip
    new["v_class"] = v_class
    new["v0"] = free * rng.normal(1.0, 0.08, n) * np.where(truck, 0.88, np.where(moto, 1.05, 1.0))
    new["headway_s"] = rng.normal(1.35, 0.25, n).clip(0.9, 2.2) + np.where(truck, 0.4, 0.0)
    new["a_max"] = np.where(truck, rng.uniform(1.3, 2.3, n), rng.uniform(2.6, 4.4, n))
    new["b_comf"] = rng.uniform(5.0, 7.0, n)
    new["s0"] = rng.uniform(5.5, 9.0, n)
    new["offset_x"] = rng.normal(0.0, 0.6, n).clip(-1.5, 1.5)
    new["change_dur_s"] = 1.0
    new["change_s"] = COOLDOWN_S
    new["noise_x"], new["noise_y"], new["noise_a"] = rng.normal(0.0, NOISE_SD[:, None], (3, n))
    new["uid"] = sim.next_uid + np.arange(n)
    sim.next_uid += n
    sim.created.append(new[["uid", "length", "width", "v_class"]])
    return new


def _run(sim: _Simulation, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Warm up, then run n_frames steps. Returns the observed rows (R, 7) and their frames (R,).

    Columns: uid, Local_Y, Local_X (noise-free, ft), v (ft/s), acc (ft/s^2), noise_x, noise_y (ft).
    """
    duration_s = n_frames * DT_S
    phase = float(sim.rng.uniform(0, 2 * np.pi))
    blocks: list[np.ndarray] = []
    counts = np.zeros(n_frames, np.int64)
    for step in range(-round(WARMUP_S / DT_S), n_frames):
        cap = bottleneck_cap_fps(sim.regime, step * DT_S, duration_s, phase)
        index = _lane_index(sim.fleet)
        acc = _accelerations(sim.fleet, index, sim.roadway, cap)
        _change_lanes(sim, index, acc, step)
        _move(sim, acc)
        if step >= 0:
            rows = _observe(sim.fleet, sim.roadway)
            blocks.append(rows)
            counts[step] = len(rows)
        _enter(sim, index)
        _leave(sim)
    frames = np.repeat(np.arange(n_frames, dtype=np.int32), counts)
    return np.concatenate(blocks), frames


def _lane_index(fleet: np.ndarray) -> _LaneIndex:
    changing = np.flatnonzero(fleet["from_lane"] != fleet["lane"])
    vehicle = np.concatenate([np.arange(len(fleet)), changing])
    lane = np.concatenate([fleet["lane"], fleet["from_lane"][changing]])
    keys = lane * KEY_LANE + fleet["y"][vehicle] + KEY_OFFSET
    order = np.argsort(keys, kind="stable")
    return _LaneIndex(keys[order], vehicle[order], lane[order])


def _neighbours_at(
    index: _LaneIndex, lanes: np.ndarray, ys: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Fleet rows of the first vehicle at or ahead of, and the last behind, (lane, y); -1 if none."""
    n = len(index.keys)
    if n == 0:
        none = np.full(len(lanes), -1)
        return none, none
    pos = np.searchsorted(index.keys, lanes * KEY_LANE + ys + KEY_OFFSET)
    ahead, behind = np.minimum(pos, n - 1), np.maximum(pos - 1, 0)
    leader = np.where((pos < n) & (index.lane[ahead] == lanes), index.vehicle[ahead], -1)
    follower = np.where((pos > 0) & (index.lane[behind] == lanes), index.vehicle[behind], -1)
    return leader, follower


def _idm(fleet: np.ndarray, rows: np.ndarray, v0: np.ndarray, gap: np.ndarray,
         v_lead: np.ndarray) -> np.ndarray:  # fmt: skip
    """IDM acceleration (ft/s^2) of fleet rows behind a leader gap ft away (inf: none) at v_lead.

    The free-road term is floored at -b: a driver entering a slower zone brakes comfortably.
    """
    v, a, b = fleet["v"][rows], fleet["a_max"][rows], fleet["b_comf"][rows]
    free = np.maximum(1.0 - (v / v0) ** 4, -b / a)
    dynamic = v * fleet["headway_s"][rows] + v * (v - v_lead) / (2.0 * np.sqrt(a * b))
    s_star = fleet["s0"][rows] + np.maximum(dynamic, 0.0)
    return a * (free - (s_star / np.maximum(gap, 0.5)) ** 2)


def _desired_speed(fleet: np.ndarray, roadway: Roadway, cap_fps: float) -> np.ndarray:
    """Desired speed (N,) ft/s: the driver's own, capped inside the bottleneck."""
    y = fleet["y"] - roadway.length_ft
    inside = (y >= roadway.bottleneck_ft[0]) & (y <= roadway.bottleneck_ft[1])
    return np.where(inside, np.minimum(fleet["v0"], cap_fps), fleet["v0"])


def _gap_to(fleet: np.ndarray, rows: np.ndarray, leader: np.ndarray, y: np.ndarray):
    """Gap (ft, inf without a leader) from positions y to leader rows (-1: none) and their speed."""
    has = leader >= 0
    safe = np.where(has, leader, rows)
    gap = np.where(has, fleet["y"][safe] - fleet["length"][safe] - y, np.inf)
    return gap, np.where(has, fleet["v"][safe], fleet["v"][rows])


def _accelerations(fleet: np.ndarray, index: _LaneIndex, roadway: Roadway,
                   cap_fps: float) -> np.ndarray:  # fmt: skip
    """IDM acceleration (N,) ft/s^2 of every vehicle: the harder of its lanes' constraints."""
    veh = index.vehicle
    leader = np.full(len(veh), -1)
    leader[:-1] = np.where(index.lane[1:] == index.lane[:-1], veh[1:], -1)
    gap, v_lead = _gap_to(fleet, veh, leader, fleet["y"][veh])
    if roadway.extra_lane_ft is not None:
        extra, end = roadway.lanes, roadway.extra_lane_ft[1]
        bound = (index.lane == extra) & (fleet["lane"][veh] == extra)
        if roadway.extra_lane_exits:
            bound &= ~fleet["exits"][veh]
        gap_end = np.where(bound, end - fleet["y"][veh], np.inf)  # the lane's end, a standing obstacle
        closer = gap_end < gap
        gap, v_lead = np.where(closer, gap_end, gap), np.where(closer, 0.0, v_lead)
    acc_entry = _idm(fleet, veh, _desired_speed(fleet, roadway, cap_fps)[veh], gap, v_lead)
    acc = np.full(len(fleet), np.inf)
    np.minimum.at(acc, veh, acc_entry)
    return acc


def _change_lanes(sim: _Simulation, index: _LaneIndex, acc: np.ndarray, step: int) -> None:
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
    lane = fleet["lane"][rows]
    best_gain, best_lane = np.full(rows.size, CHANGE_THRESHOLD_FPS2), lane.copy()
    for direction in (-1, 1):
        target = (lane + direction).astype(np.int16)
        gain = _change_gain(fleet, index, acc, rows, target, sim.roadway)
        better = gain > best_gain
        best_gain, best_lane = np.where(better, gain, best_gain), np.where(better, target, best_lane)
    moving = rows[best_lane != lane]
    fleet["from_lane"][moving] = fleet["lane"][moving]
    fleet["lane"][moving] = best_lane[best_lane != lane]
    fleet["change_s"][moving] = 0.0
    fleet["change_dur_s"][moving] = sim.rng.uniform(3.0, 5.0, moving.size)


def _change_gain(fleet: np.ndarray, index: _LaneIndex, acc: np.ndarray, rows: np.ndarray,
                 target: np.ndarray, roadway: Roadway) -> np.ndarray:  # fmt: skip
    """MOBIL incentive (ft/s^2) of moving rows to target lanes; -inf where unsafe or impossible."""
    y = fleet["y"][rows]
    leader, follower = _neighbours_at(index, target, y)
    gap_ahead, v_ahead = _gap_to(fleet, rows, leader, y)
    v0 = fleet["v0"]
    own_new = _idm(fleet, rows, v0[rows], gap_ahead, v_ahead)
    has_f = follower >= 0
    behind = np.where(has_f, follower, rows)
    gap_behind = np.where(has_f, y - fleet["length"][rows] - fleet["y"][behind], np.inf)
    follower_new = _idm(fleet, behind, v0[behind], gap_behind, fleet["v"][rows])
    follower_loss = np.where(has_f, follower_new - acc[behind], 0.0)
    bias = _change_bias(fleet, rows, target, roadway)
    gain = own_new - acc[rows] + POLITENESS * follower_loss + bias
    safe_brake = SAFE_BRAKE_FPS2 + np.maximum(bias, 0.0)  # mandatory moves accept harder braking
    safe = (
        (gap_ahead > MIN_GAP_FT) & (gap_behind > MIN_GAP_FT)
        & (own_new > -safe_brake) & (np.where(has_f, follower_new, 0.0) > -safe_brake)
    )  # fmt: skip
    return np.where(safe & _lane_open(fleet, rows, target, roadway), gain, -np.inf)


def _lane_open(fleet: np.ndarray, rows: np.ndarray, target: np.ndarray,
               roadway: Roadway) -> np.ndarray:  # fmt: skip
    """Whether target lanes exist at the rows' positions and may be entered."""
    is_open = (target >= 1) & (target <= roadway.main_lanes)
    if roadway.extra_lane_ft is not None and roadway.extra_lane_exits:
        start, end = roadway.extra_lane_ft
        room = np.where(fleet["exits"][rows], 60.0, 500.0)  # through traffic leaves it early
        y = fleet["y"][rows]
        is_open |= (target == roadway.lanes) & (y > start + 50.0) & (y < end - room)
    return is_open


def _change_bias(fleet: np.ndarray, rows: np.ndarray, target: np.ndarray,
                 roadway: Roadway) -> np.ndarray:  # fmt: skip
    """Extra incentive (ft/s^2) for mandatory moves, growing as the decision point nears."""
    bias = np.zeros(len(rows))
    if roadway.extra_lane_ft is None:
        return bias
    start, end = roadway.extra_lane_ft
    y, lane = fleet["y"][rows], fleet["lane"][rows]
    direction = target - lane
    exiting = fleet["exits"][rows] & roadway.extra_lane_exits & (y < end)
    through_in_extra = (lane == roadway.lanes) & ~exiting
    urgency_end = np.clip((y - start) / (end - start - 100.0), 0.0, 1.0)
    bias += np.where(through_in_extra & (direction == -1), 1.0 + 8.0 * urgency_end**2, 0.0)
    bias += np.where((target == roadway.lanes) & ~exiting, -1.5, 0.0)
    urgency_exit = np.clip((y - (end - 1500.0)) / 1200.0, 0.0, 1.0)
    bias += np.where(exiting, direction * (0.5 + 6.0 * urgency_exit), 0.0)
    return bias


def _lateral_ft(fleet: np.ndarray) -> np.ndarray:
    """Noise-free Local_X (N,) ft: lane centre plus offset, eased across a lane change."""
    frac = np.clip(fleet["change_s"] / fleet["change_dur_s"], 0.0, 1.0)
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
    done = (fleet["from_lane"] != fleet["lane"]) & (fleet["change_s"] >= fleet["change_dur_s"])
    fleet["from_lane"][done] = fleet["lane"][done]
    shocks = sim.rng.standard_normal((3, n)) * (NOISE_SD * np.sqrt(1 - NOISE_RHO**2))[:, None]
    for k, name in enumerate(("noise_x", "noise_y", "noise_a")):
        fleet[name] = NOISE_RHO[k] * fleet[name] + shocks[k]


def _observe(fleet: np.ndarray, roadway: Roadway) -> np.ndarray:
    """The rows (K, 7) of the vehicles inside the view, columns as documented in `_run`."""
    inside = (fleet["y"] >= 0.0) & (fleet["y"] <= roadway.length_ft)
    visible = fleet[inside]
    columns = (visible["uid"], visible["y"], _lateral_ft(visible), visible["v"], visible["acc"],
               visible["noise_x"], visible["noise_y"])  # fmt: skip
    return np.column_stack(columns).astype(np.float64)


def _enter(sim: _Simulation, index: _LaneIndex) -> None:
    """Arrivals join the entry queues; the head of each queue enters when its lane has room."""
    sim.pending = np.minimum(sim.pending + sim.rng.poisson(sim.entry_rate * DT_S), MAX_PENDING)
    points = np.flatnonzero(sim.pending > 0)
    if points.size == 0:
        return
    lanes, ys = sim.entry_lane[points], sim.entry_y[points]
    leader, _ = _neighbours_at(index, lanes, ys)
    gap, v_lead = _gap_to(sim.fleet, np.zeros_like(leader), leader, ys) if len(sim.fleet) else (
        np.full(points.size, np.inf), np.zeros(points.size))  # fmt: skip
    free = sim.roadway.free_speed_fps * np.where(lanes > sim.roadway.main_lanes, 0.7, 0.95)
    v_in = np.where(leader >= 0, np.minimum(v_lead, free), free)
    fits = gap >= ENTRY_GAP_FT + ENTRY_HEADWAY_S * v_in
    if not fits.any():
        return
    entering = points[fits]
    new = _new_vehicles(sim, entering.size)
    new["y"] = ys[fits]
    new["lane"] = new["from_lane"] = lanes[fits]
    new["v"] = np.minimum(v_in[fits], new["v0"])
    new["exits"] = sim.rng.random(entering.size) < sim.entry_exit_share[entering]
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


def _observe_rows(observed: np.ndarray, frames: np.ndarray, static: np.ndarray, roadway: Roadway,
                  frame0_ms: int, rng: np.random.Generator) -> pl.DataFrame:  # fmt: skip
    """NGSIM rows from the simulated states: ids, jitter, lanes, neighbours, headways, rounding.

    `observed` (R, 7) and `frames` (R,) come from `_run`; `static` holds every created vehicle's
    uid, length, width and class, in uid order. Returns `schema.RAW_SCHEMA` rows sorted by
    (vehicle_id, frame_id).
    """
    uid = observed[:, 0].astype(np.int64)
    vehicle_id = _ids_by_entry(uid, frames, observed[:, 1])
    order = np.lexsort((frames, vehicle_id))
    uid, vehicle_id, frames, obs = uid[order], vehicle_id[order], frames[order], observed[order]
    n = len(uid)
    white = rng.standard_normal((2, n)) * np.array([[0.1], [0.15]])  # ft, uncorrelated part
    local_y = np.round(obs[:, 1] + obs[:, 6] + white[1], 3)
    local_x = np.round(obs[:, 2] + obs[:, 5] + white[0], 3)
    speed = np.round(np.maximum(obs[:, 3] * (1.0 + 0.01 * rng.standard_normal(n)), 0.0), 2)
    accel = np.round(obs[:, 4] + 0.15 * rng.standard_normal(n) * (obs[:, 3] > 0), 2)
    lane = lane_of_ft(local_x, roadway)
    preceding, following, space = _neighbours_in_view(vehicle_id, frames, lane, local_y)
    timed = (preceding != 0) & (speed > 0)
    time_headway = np.where(timed, np.minimum(space / np.where(timed, speed, 1.0), 9999.99), 9999.99)
    global_x, global_y = to_global_ft(local_x, local_y, roadway)
    _, first, counts = np.unique(vehicle_id, return_index=True, return_counts=True)
    columns = {
        schema.VEHICLE_ID: vehicle_id,
        schema.FRAME_ID: frames,
        schema.TOTAL_FRAMES: np.repeat(counts, counts),
        schema.GLOBAL_TIME: frame0_ms + 100 * frames.astype(np.int64),
        schema.LOCAL_X: local_x,
        schema.LOCAL_Y: local_y,
        schema.GLOBAL_X: np.round(global_x, 3),
        schema.GLOBAL_Y: np.round(global_y, 3),
        schema.V_LENGTH: np.round(static["length"][uid], 1),
        schema.V_WIDTH: np.round(static["width"][uid], 1),
        schema.V_CLASS: static["v_class"][uid],
        schema.V_VEL: speed,
        schema.V_ACC: accel,
        schema.LANE_ID: lane,
        schema.PRECEDING: preceding,
        schema.FOLLOWING: following,
        schema.SPACE_HEADWAY: np.round(space, 2),
        schema.TIME_HEADWAY: np.round(time_headway, 2),
    }
    return pl.DataFrame(columns).cast(dict(schema.RAW_SCHEMA))


def _ids_by_entry(uid: np.ndarray, frames: np.ndarray, local_y: np.ndarray) -> np.ndarray:
    """Vehicle_ID (R,) from 1 in order of first appearance; at frame 0, downstream vehicles first."""
    unique, first, inverse = np.unique(uid, return_index=True, return_inverse=True)
    rank = np.empty(len(unique), np.int64)
    rank[np.lexsort((-local_y[first], frames[first]))] = np.arange(1, len(unique) + 1)
    return rank[inverse]


def _neighbours_in_view(vehicle_id: np.ndarray, frames: np.ndarray, lane: np.ndarray,
                        local_y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Preceding and following Vehicle_ID (0: none) in the same frame and lane, and the front-to-
    front space headway (ft, 0 without a preceding vehicle), for rows (R,)."""
    order = np.lexsort((vehicle_id, local_y, lane, frames))
    same = (frames[order][1:] == frames[order][:-1]) & (lane[order][1:] == lane[order][:-1])
    ids, ys = vehicle_id[order], local_y[order]
    preceding, following, space = (np.zeros(len(order), np.int64), np.zeros(len(order), np.int64),
                                   np.zeros(len(order)))  # fmt: skip
    preceding[order[:-1]] = np.where(same, ids[1:], 0)
    following[order[1:]] = np.where(same, ids[:-1], 0)
    space[order[:-1]] = np.where(same, ys[1:] - ys[:-1], 0.0)
    return preceding, following, space
