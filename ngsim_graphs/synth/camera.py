"""How NGSIM's camera records the simulated vehicles: as NGSIM rows, in NGSIM units (feet).

Global coordinates are a rotation and offset of the local ones into state-plane-like feet. Records
carry NGSIM's measurement jitter and its rounding; lanes, neighbours and headways are read from the
jittered positions, as NGSIM derived them from its own.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import polars as pl

from ngsim_graphs import schema
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.synth.road import Roadway, lane_of_ft

WHITE_NOISE_FT = (0.04, 0.15)  # (Local_X, Local_Y) uncorrelated part of the measurement error
ACCEL_NOISE_FPS2 = 0.15
# The error of the recorded speed grows from nothing at a standstill (a stopped vehicle reads 0)
# to its full size at this speed (3 m/s). Were it full at a crawl, a crawling vehicle's speed
# would often read above the build's 2 m/s at which headings start to count, and its heading
# would be that of its position errors rather than of its motion.
FULL_SPEED_ERROR_FPS = 10.0


def to_global_ft(
    local_x_ft: np.ndarray, local_y_ft: np.ndarray, roadway: Roadway
) -> tuple[np.ndarray, np.ndarray]:
    """(Global_X, Global_Y) ft of local positions (N,): y along the heading, x to its right."""
    sin_h, cos_h = np.sin(roadway.heading_rad), np.cos(roadway.heading_rad)
    global_x = roadway.origin_ft[0] + local_y_ft * sin_h + local_x_ft * cos_h
    global_y = roadway.origin_ft[1] + local_y_ft * cos_h - local_x_ft * sin_h
    return global_x, global_y


class Sightings(NamedTuple):
    """One entry per (vehicle, frame) inside the view; arrays (R,), frames in increasing order.

    Positions, speed and acceleration are the noise-free simulated state; noise_* is the temporally
    correlated part of the measurement error (ft).
    """

    uid: np.ndarray  # simulated vehicle, dense from 0 in order of creation
    frame: np.ndarray
    y_ft: np.ndarray
    x_ft: np.ndarray
    v_fps: np.ndarray
    acc_fps2: np.ndarray
    noise_x_ft: np.ndarray
    noise_y_ft: np.ndarray
    noise_v_fps: np.ndarray  # of the recorded speed
    noise_acc_fps2: np.ndarray  # of the recorded acceleration


def observed_rows(
    seen: Sightings,
    vehicles: np.ndarray,
    roadway: Roadway,
    frame0_ms: int,
    rng: np.random.Generator,
) -> pl.DataFrame:
    """NGSIM rows of a recording: ids by entry, jitter, lanes, neighbours, headways, rounding.

    `vehicles` is a structured array with fields length, width (ft) and v_class, indexed by uid.
    Returns `ns.RAW_SCHEMA` rows sorted by (vehicle_id, frame_id).
    """
    vehicle_id = _ids_by_entry(seen.uid, seen.frame, seen.y_ft)
    order = np.lexsort((seen.frame, vehicle_id))
    seen, vehicle_id = Sightings(*(column[order] for column in seen)), vehicle_id[order]
    local_x, local_y, speed, accel = _measure(seen, roadway, rng)
    lane = lane_of_ft(local_x, roadway)
    preceding, following, space = _neighbours_in_view(vehicle_id, seen.frame, lane, local_y)
    timed = (preceding != ns.NO_NEIGHBOUR_ID) & (speed > 0)
    no_leader = ns.NO_LEADER_TIME_HEADWAY_S
    headway_s = np.minimum(space / np.where(timed, speed, 1.0), no_leader)
    time_headway = np.where(timed, headway_s, no_leader)
    global_x, global_y = to_global_ft(local_x, local_y, roadway)
    counts = np.unique(vehicle_id, return_counts=True)[1]
    size = vehicles[seen.uid]
    columns = {
        schema.VEHICLE_ID: vehicle_id,
        schema.FRAME_ID: seen.frame,
        ns.TOTAL_FRAMES: np.repeat(counts, counts),
        schema.GLOBAL_TIME: frame0_ms + 100 * seen.frame.astype(np.int64),
        ns.LOCAL_X: local_x,
        ns.LOCAL_Y: local_y,
        ns.GLOBAL_X: np.round(global_x, 3),
        ns.GLOBAL_Y: np.round(global_y, 3),
        ns.V_LENGTH: np.round(size["length"], 1),
        ns.V_WIDTH: np.round(size["width"], 1),
        schema.V_CLASS: size["v_class"],
        ns.V_VEL: speed,
        ns.V_ACC: accel,
        schema.LANE_ID: lane,
        schema.PRECEDING: preceding,
        schema.FOLLOWING: following,
        ns.SPACE_HEADWAY: np.round(space, 2),
        ns.TIME_HEADWAY: np.round(time_headway, 2),
    }
    return pl.DataFrame(columns).cast(dict(ns.RAW_SCHEMA))


def _measure(
    seen: Sightings, roadway: Roadway, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Local_X, Local_Y (ft, 3 decimals), v_Vel (ft/s) and v_Acc (ft/s^2, 2 decimals), (R,) each:
    the simulated state plus correlated and white measurement noise (v_Vel's error: correlated
    only, faded in over the slowest speeds). Speeds are never negative and a stopped vehicle reads
    exactly 0."""
    n = len(seen.uid)
    white = rng.standard_normal((2, n)) * np.array(WHITE_NOISE_FT)[:, None]
    local_x = np.round(seen.x_ft + seen.noise_x_ft + white[0], 3)
    local_y = np.clip(seen.y_ft + seen.noise_y_ft + white[1], 0.0, roadway.length_ft).round(3)
    moving = seen.v_fps > 0
    fade = np.minimum(seen.v_fps / FULL_SPEED_ERROR_FPS, 1.0)
    speed = np.maximum(seen.v_fps + seen.noise_v_fps * fade, 0.0).round(2)
    white = ACCEL_NOISE_FPS2 * rng.standard_normal(n)
    accel = np.round(seen.acc_fps2 + (seen.noise_acc_fps2 + white) * moving, 2)
    return local_x, local_y, speed, accel


def _ids_by_entry(uid: np.ndarray, frames: np.ndarray, local_y: np.ndarray) -> np.ndarray:
    """Vehicle_ID (R,) from 1 in order of first appearance; at frame 0 the downstream ones first."""
    unique, first, inverse = np.unique(uid, return_index=True, return_inverse=True)
    rank = np.empty(len(unique), np.int64)
    rank[np.lexsort((-local_y[first], frames[first]))] = np.arange(1, len(unique) + 1)
    return rank[inverse]


def _neighbours_in_view(
    vehicle_id: np.ndarray, frames: np.ndarray, lane: np.ndarray, local_y: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Preceding and following Vehicle_ID (0: none) in the same frame and lane, and the front-to-
    front space headway (ft, 0 without a preceding vehicle), for rows (R,)."""
    order = np.lexsort((vehicle_id, local_y, lane, frames))
    same = (frames[order][1:] == frames[order][:-1]) & (lane[order][1:] == lane[order][:-1])
    ids, ys = vehicle_id[order], local_y[order]
    preceding, following = np.zeros(len(order), np.int64), np.zeros(len(order), np.int64)
    space = np.zeros(len(order))
    preceding[order[:-1]] = np.where(same, ids[1:], ns.NO_NEIGHBOUR_ID)
    following[order[1:]] = np.where(same, ids[:-1], ns.NO_NEIGHBOUR_ID)
    space[order[:-1]] = np.where(same, ys[1:] - ys[:-1], 0.0)
    return preceding, following, space
