"""Tiny highD recordings written in code: a tracks row is a dict of highD's column names.

The image of every recording here: upper lanes 2, 3 between the markings y = 8.0, 11.5, 15.0;
lower lanes 5, 6 between y = 18.0, 21.5, 25.0 (image y grows downwards). Direction 2 drives on
the lower lanes towards +x, direction 1 on the upper lanes towards -x.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from ngsim_graphs.sources.highd import schema as hs

UPPER_MARKINGS = (8.0, 11.5, 15.0)
LOWER_MARKINGS = (18.0, 21.5, 25.0)


def track_rows(
    vehicle_id: int, frames: range, x0: float, y: float, x_velocity: float, **fields: float
) -> list[dict[str, float]]:
    """Rows of one vehicle moving at a constant xVelocity (m/s): x = x0 at frames[0]."""
    rows = []
    for frame in frames:
        row = dict.fromkeys(hs.HIGHD_TRACKS_HEADER, 0)
        row.update({hs.HIGHD_FRAME: frame, hs.HIGHD_ID: vehicle_id, hs.HIGHD_WIDTH: 4.0, hs.HIGHD_HEIGHT: 2.0,
                    hs.HIGHD_X: round(x0 + x_velocity * (frame - frames[0]) / 25, 6), hs.HIGHD_Y: y,
                    hs.HIGHD_X_VELOCITY: x_velocity, hs.HIGHD_LANE_ID: 5})  # fmt: skip
        row.update(fields)
        rows.append(row)
    return rows


def csv_text(header: tuple[str, ...], rows: list[dict[str, object]]) -> str:
    lines = [",".join(header)] + [",".join(str(row.get(c, 0)) for c in header) for row in rows]
    return "\n".join(lines) + "\n"


def write_recording(
    folder: Path,
    rows: list[dict[str, float]],
    vehicles: dict[int, tuple[str, int]],
    number: int = 1,
    location_id: int = 2,
    frame_rate: int = 25,
) -> Path:
    """Write NN_tracks.csv, NN_tracksMeta.csv (vehicles: id -> (class, drivingDirection)) and
    NN_recordingMeta.csv into `folder`; returns the tracks file."""
    folder.mkdir(parents=True, exist_ok=True)
    prefix = f"{number:02d}"
    tracks = folder / f"{prefix}_tracks.csv"
    tracks.write_text(csv_text(hs.HIGHD_TRACKS_HEADER, rows))
    frames = Counter(row[hs.HIGHD_ID] for row in rows)  # numFrames: the track's rows
    meta_rows = [{hs.HIGHD_ID: vid, hs.HIGHD_WIDTH: 4.0, hs.HIGHD_HEIGHT: 2.0, hs.HIGHD_CLASS: cls,
                  hs.HIGHD_DRIVING_DIRECTION: direction, hs.HIGHD_NUM_FRAMES: frames[vid]}
                 for vid, (cls, direction) in vehicles.items()]  # fmt: skip
    (folder / f"{prefix}_tracksMeta.csv").write_text(
        csv_text(hs.HIGHD_TRACKS_META_HEADER, meta_rows)
    )
    recording = {hs.HIGHD_ID: number, hs.HIGHD_FRAME_RATE: frame_rate, hs.HIGHD_LOCATION_ID: location_id,
                 "speedLimit": -1, "month": "09.2017", "weekDay": "Tue", "startTime": "08:38",
                 hs.HIGHD_UPPER_LANE_MARKINGS: ";".join(map(str, UPPER_MARKINGS)),
                 hs.HIGHD_LOWER_LANE_MARKINGS: ";".join(map(str, LOWER_MARKINGS))}  # fmt: skip
    (folder / f"{prefix}_recordingMeta.csv").write_text(
        csv_text(hs.HIGHD_RECORDING_META_HEADER, [recording])
    )
    return tracks


TWO_DIRECTIONS = {1: ("Car", 2), 2: ("Truck", 1)}  # the vehicles of two_directions_rows
LONG = range(1, 1101)  # 44 s: one track of either vehicle holds windows of 8.2 s


def two_directions_rows(frames: range = range(1, 301)) -> list[dict[str, float]]:
    """Vehicle 1 (Car) on the lower lanes at 25 m/s, vehicle 2 (Truck) on the upper lanes at
    -25 m/s: 1 m per frame each. Vehicle 1's rows come first: frame f on line f + 1 (from 1)."""
    rows = track_rows(1, frames, x0=100.0, y=19.0, x_velocity=25.0)
    return rows + track_rows(2, frames, x0=400.0, y=12.0, x_velocity=-25.0, width=5.0, laneId=3)


def two_directions(
    folder: Path, frames: range = range(1, 301), number: int = 1, location_id: int = 2
) -> Path:
    """The recording of two_directions_rows; returns the tracks file."""
    rows = two_directions_rows(frames)
    return write_recording(folder, rows, TWO_DIRECTIONS, number, location_id)
