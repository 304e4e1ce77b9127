"""How the simulated drivers drive: car-following by the improved Intelligent Driver Model
(IIDM, Treiber and Kesting 2013) and lane changes by MOBIL (Kesting, Treiber, Helbing 2007), on
an index of the lanes' occupancy. Functions of the fleet (`traffic.FLEET_DTYPE`), vectorised over
its vehicles; NGSIM's units: feet, seconds, feet/s, feet/s^2.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ngsim_graphs.synth.road import Roadway, change_bias, lane_open

KEY_LANE = 1.0e5  # sort key lane * KEY_LANE + y + KEY_OFFSET orders entries by lane, then y
KEY_OFFSET = 1.0e4
POLITENESS = 0.2  # MOBIL's weight of the new follower's disadvantage
SAFE_BRAKE_FPS2 = 8.0  # MOBIL safety: the new follower need not brake harder than this
MIN_GAP_FT = 3.0
YIELD_FT, YIELD_FPS = 80.0, 8.0  # drivers let in a vehicle stuck this close to its lane's end
# Relaxation: a driver changing lanes accepts a gap at which it, and its new follower, keep only a
# share of their usual time headway, and both drift back to it over RELAX_S. Without it a dense
# lane almost never offers a gap the IDM deems safe, and lane changes are rarer than in the real
# sample that docs/synthetic.md compares with.
ACCEPTED_HEADWAY = 0.75  # share of the usual time headway
RELAX_S = 10.0  # time constant of the return to the usual headway
# Past this share of its lateral move a changing vehicle has left its old lane: followers there
# no longer follow it.
LEFT_OLD_LANE = 0.5


class LaneIndex(NamedTuple):
    """Lane occupancy: (E,) entries sorted by lane then y; a changing vehicle has two entries until
    it has left its old lane (LEFT_OLD_LANE)."""

    keys: np.ndarray
    vehicle: np.ndarray  # fleet row of each entry
    lane: np.ndarray
    courtesy: np.ndarray  # bool: the entry of a vehicle waiting to merge, in the lane it waits for


def lane_index(fleet: np.ndarray, roadway: Roadway) -> tuple[LaneIndex, LaneIndex]:
    """Occupancy for car-following, and the same without courtesy entries for gap searches.

    A vehicle stuck near the end of the extra lane that must leave it also appears in the lane it
    waits for: the drivers there stop behind it, as real drivers let a waiting car in.
    """
    leaving = (fleet["from_lane"] != fleet["lane"]) & (fleet["change_frac"] < LEFT_OLD_LANE)
    changing = np.flatnonzero(leaving)
    waiting = np.zeros(0, np.int64)
    if roadway.extra_lane_ft is not None:
        must_leave = ~fleet["exits"] if roadway.extra_lane_exits else True
        waiting = np.flatnonzero(
            (fleet["lane"] == roadway.lanes)
            & (fleet["from_lane"] == roadway.lanes)
            & must_leave
            & (fleet["y"] > roadway.extra_lane_ft[1] - YIELD_FT)
            & (fleet["v"] < YIELD_FPS)
        )
    vehicle = np.concatenate([np.arange(len(fleet)), changing, waiting])
    lane = np.concatenate(
        [fleet["lane"], fleet["from_lane"][changing], np.full(waiting.size, roadway.main_lanes)]
    )
    keys = lane * KEY_LANE + fleet["y"][vehicle] + KEY_OFFSET
    order = np.argsort(keys, kind="stable")
    courtesy = order >= len(fleet) + changing.size
    following = LaneIndex(keys[order], vehicle[order], lane[order], courtesy)
    if waiting.size == 0:
        return following, following
    real = ~courtesy
    return following, LaneIndex(
        keys[order][real], vehicle[order][real], lane[order][real], courtesy[real]
    )


def neighbours_at(
    index: LaneIndex, lanes: np.ndarray, ys: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Fleet rows of the first vehicle at or ahead of (lane, y) and the last behind it; -1: none."""
    n = len(index.keys)
    if n == 0:
        none = np.full(len(lanes), -1)
        return none, none
    pos = np.searchsorted(index.keys, lanes * KEY_LANE + ys + KEY_OFFSET)
    ahead, behind = np.minimum(pos, n - 1), np.maximum(pos - 1, 0)
    leader = np.where((pos < n) & (index.lane[ahead] == lanes), index.vehicle[ahead], -1)
    follower = np.where((pos > 0) & (index.lane[behind] == lanes), index.vehicle[behind], -1)
    return leader, follower


def idm(
    fleet: np.ndarray,
    rows: np.ndarray,
    v0: np.ndarray,
    gap: np.ndarray,
    v_lead: np.ndarray,
    headway_s: np.ndarray | None = None,
) -> np.ndarray:
    """IIDM acceleration (ft/s^2) of fleet rows behind a leader gap ft away (inf: none) at v_lead.

    The improved IDM (Treiber and Kesting 2013) keeps the IDM's dynamics but not its low free-flow
    capacity: a driver cruises at v0 until the gap falls to the desired one. Above v0 (entering the
    bottleneck) it brakes towards v0 at no more than about b. The time headway is the driver's
    own less its relaxation (`relax_s`), unless `headway_s` gives another.
    """
    v, a, b = fleet["v"][rows], fleet["a_max"][rows], fleet["b_comf"][rows]
    if headway_s is None:
        headway_s = fleet["headway_s"][rows] - fleet["relax_s"][rows]
    dynamic = v * headway_s + v * (v - v_lead) / (2.0 * np.sqrt(a * b))
    z = (fleet["s0"][rows] + np.maximum(dynamic, 0.0)) / np.maximum(gap, 0.5)
    below = v <= v0
    ratio = np.where(below, v / v0, v0 / np.maximum(v, 1e-6))
    a_free = np.where(below, a * (1.0 - ratio**4), -b * (1.0 - ratio ** (4.0 * a / b)))
    close = a * (1.0 - z**2)
    smooth = a_free * (1.0 - np.minimum(z, 1.0) ** (2.0 * a / np.maximum(a_free, 1e-9)))
    return np.where(
        below, np.where(z >= 1.0, close, smooth), a_free + np.where(z >= 1.0, close, 0.0)
    )


def desired_speed(fleet: np.ndarray, roadway: Roadway, cap_fps: float) -> np.ndarray:
    """Desired speed (N,) ft/s: the driver's own, capped inside the bottleneck."""
    y = fleet["y"] - roadway.length_ft
    inside = (y >= roadway.bottleneck_ft[0]) & (y <= roadway.bottleneck_ft[1])
    return np.where(inside, np.minimum(fleet["v0"], cap_fps), fleet["v0"])


def gap_to(
    fleet: np.ndarray, rows: np.ndarray, leader: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Gap (ft; inf without a leader) from positions y to leader rows (-1: none), and the leaders'
    speed (the rows' own where there is none, so that nothing is approached)."""
    has = leader >= 0
    safe = np.where(has, leader, rows)
    gap = np.where(has, fleet["y"][safe] - fleet["length"][safe] - y, np.inf)
    return gap, np.where(has, fleet["v"][safe], fleet["v"][rows])


def accelerations(
    fleet: np.ndarray, index: LaneIndex, roadway: Roadway, cap_fps: float
) -> np.ndarray:
    """IIDM acceleration (N,) ft/s^2 of every vehicle: the harder of its lanes' constraints."""
    veh = index.vehicle
    leader = np.full(len(veh), -1)
    leader[:-1] = np.where(index.lane[1:] == index.lane[:-1], veh[1:], -1)
    gap, v_lead = gap_to(fleet, veh, leader, fleet["y"][veh])
    alongside = np.flatnonzero(index.courtesy[1:] & (gap[:-1] < 0.0))
    if alongside.size:  # too late to let that one in: follow the vehicle beyond it
        beyond = np.minimum(alongside + 2, len(veh) - 1)
        same = (alongside + 2 < len(veh)) & (index.lane[beyond] == index.lane[alongside])
        leader[alongside] = np.where(same, veh[beyond], -1)
        gap, v_lead = gap_to(fleet, veh, leader, fleet["y"][veh])
    if roadway.extra_lane_ft is not None:
        extra, end = roadway.lanes, roadway.extra_lane_ft[1]
        bound = (index.lane == extra) & (fleet["lane"][veh] == extra)
        if roadway.extra_lane_exits:
            bound &= ~fleet["exits"][veh]
        gap_end = np.where(bound, end - fleet["y"][veh], np.inf)  # the lane's end stands still
        closer = gap_end < gap
        gap, v_lead = np.where(closer, gap_end, gap), np.where(closer, 0.0, v_lead)
    acc_entry = idm(fleet, veh, desired_speed(fleet, roadway, cap_fps)[veh], gap, v_lead)
    acc_entry[index.courtesy] = np.inf  # a waiting vehicle creeps on in its own lane
    acc = np.full(len(fleet), np.inf)
    np.minimum.at(acc, veh, acc_entry)
    return acc


def change_gain(
    fleet: np.ndarray,
    index: LaneIndex,
    acc: np.ndarray,
    rows: np.ndarray,
    target: np.ndarray,
    roadway: Roadway,
) -> np.ndarray:
    """MOBIL incentive (ft/s^2) of moving rows to target lanes; -inf where unsafe or impossible.
    The mover and its new follower are judged at the time headway they accept (relaxation)."""
    y = fleet["y"][rows]
    leader, follower = neighbours_at(index, target, y)
    gap_ahead, v_ahead = gap_to(fleet, rows, leader, y)
    v0, accepted = fleet["v0"], ACCEPTED_HEADWAY * fleet["headway_s"]
    own_new = idm(fleet, rows, v0[rows], gap_ahead, v_ahead, accepted[rows])
    has_f = follower >= 0
    behind = np.where(has_f, follower, rows)
    gap_behind = np.where(has_f, y - fleet["length"][rows] - fleet["y"][behind], np.inf)
    follower_new = idm(fleet, behind, v0[behind], gap_behind, fleet["v"][rows], accepted[behind])
    follower_loss = np.where(has_f, follower_new - acc[behind], 0.0)
    exits = fleet["exits"][rows]
    bias = change_bias(roadway, fleet["lane"][rows], target, y, exits)
    gain = own_new - acc[rows] + POLITENESS * follower_loss + bias
    safe_brake = SAFE_BRAKE_FPS2 + np.maximum(bias, 0.0)  # mandatory moves accept harder braking
    safe = (
        (gap_ahead > MIN_GAP_FT)
        & (gap_behind > MIN_GAP_FT)
        & (own_new > -safe_brake)
        & (np.where(has_f, follower_new, 0.0) > -safe_brake)
    )
    return np.where(safe & lane_open(roadway, target, y, exits), gain, -np.inf)


def relax(fleet: np.ndarray, index: LaneIndex, rows: np.ndarray, target: np.ndarray) -> None:
    """Shorten the time headway (`relax_s`) of fleet rows that start to move to target lanes (N,),
    and of their new followers there, to the share they accepted (ACCEPTED_HEADWAY)."""
    _, follower = neighbours_at(index, target, fleet["y"][rows])
    for shortened in (rows, follower[follower >= 0]):
        short = (1.0 - ACCEPTED_HEADWAY) * fleet["headway_s"][shortened]
        fleet["relax_s"][shortened] = np.maximum(fleet["relax_s"][shortened], short)
