"""Tiny NGSIM inputs written in code, in each of the three formats.

A row is a dict of canonical column names (ns.TXT_COLUMNS) to numbers in NGSIM units. The
writers produce the bytes a real export would, with optional quirks.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import replace
from pathlib import Path

import pytest
from aigem_fixtures import (  # noqa: F401  (shared)
    docs_demo,
    tiny_build,
    tiny_horizons_run,
    tiny_run,
    two_recording_build,
)

from ngsim_graphs import budget
from ngsim_graphs import schema as s
from ngsim_graphs.sources.ngsim import schema as ns
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS

# PyTorch's operators in the test process (and the programs the tests start) on one thread, unless
# the environment says otherwise: the tests' tensors are tiny, and a second OpenMP thread only
# waits for the first, spinning on its core, so that on a busy machine (or beside a program a
# test runs in the background) the suite took several times its CPU time. A fit's own --threads,
# or the cores ThreadChooser finds, still set its threads (aigem/cores.py). Set before any test
# module imports torch, which reads it once.
os.environ.setdefault("OMP_NUM_THREADS", "1")

US101_FIRST = OFFICIAL_RECORDINGS[0]  # us-101 0750am-0805am
I80_FIRST = OFFICIAL_RECORDINGS[1]  # i-80 0400-0415
US101_SECOND = OFFICIAL_RECORDINGS[2]  # us-101 0805am-0820am
FRAME0_OFFSET_MS = -7_000  # frame 0 a few seconds before the nominal start, as in the real data


def make_row(
    vehicle_id: int,
    frame_id: int,
    local_x_ft: float = 18.0,
    local_y_ft: float = 100.0,
    v_vel_fps: float = 30.0,
    start_ms: int = US101_FIRST.start_epoch_ms,
    **overrides: float,
) -> dict[str, float]:
    """One raw row in NGSIM units; Global_Time follows from the recording's frame-0 time."""
    row: dict[str, float] = {
        s.VEHICLE_ID: vehicle_id,
        s.FRAME_ID: frame_id,
        ns.TOTAL_FRAMES: 100,
        s.GLOBAL_TIME: start_ms + FRAME0_OFFSET_MS + 100 * frame_id,
        ns.LOCAL_X: local_x_ft,
        ns.LOCAL_Y: local_y_ft,
        ns.GLOBAL_X: 6451000.0 + local_x_ft,
        ns.GLOBAL_Y: 1873000.0 + local_y_ft,
        ns.V_LENGTH: 15.0,
        ns.V_WIDTH: 6.0,
        s.V_CLASS: 2,
        ns.V_VEL: v_vel_fps,
        ns.V_ACC: 0.0,
        s.LANE_ID: 2,
        s.PRECEDING: 0,
        s.FOLLOWING: 0,
        ns.SPACE_HEADWAY: 0.0,
        ns.TIME_HEADWAY: ns.NO_LEADER_TIME_HEADWAY_S,
    }
    row.update(overrides)
    return row


def straight_track(
    vehicle_id: int, frames: range, speed_fps: float = 30.0, x_ft: float = 18.0, **kw: float
) -> list[dict[str, float]]:
    """A vehicle driving straight along +y at constant speed, one row per frame."""
    return [
        make_row(
            vehicle_id,
            f,
            local_x_ft=x_ft,
            local_y_ft=speed_fps * 0.1 * f,
            v_vel_fps=speed_fps,
            **kw,
        )
        for f in frames
    ]


def _text(value: float | str | None, thousands: bool) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    text = f"{value:.3f}".rstrip("0").rstrip(".") if isinstance(value, float) else str(value)
    if thousands and abs(float(value)) >= 1000:
        whole, _, frac = text.partition(".")
        text = f"{int(whole):,}" + (f".{frac}" if frac else "")
    return text


def write_txt(path: Path, rows: list[dict], final_newline: bool = False) -> Path:
    """Original whitespace text: padded fields, leading/trailing spaces, no final newline."""
    lines = [
        "   " + "  ".join(_text(r[c], False).rjust(6) for c in ns.TXT_COLUMNS) + "  " for r in rows
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + ("\n" if final_newline else ""))
    return path


def _csv_bytes(header: list[str], rows: list[list[str]], bom: bool, crlf: bool) -> bytes:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\r\n" if crlf else "\n")
    writer.writerow(header)
    writer.writerows(rows)
    return (("\ufeff" if bom else "") + buffer.getvalue()).encode()


def write_period_csv(
    path: Path, rows: list[dict], header: tuple[str, ...] = ns.PERIOD_CSV_HEADER, crlf: bool = False
) -> Path:
    """Per-period CSV with a header (spelling as given), the portal's columns without Location."""
    canonical = [name.lower() for name in header]
    body = [[_text(r.get(c), False) for c in canonical] for r in rows]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(_csv_bytes(list(header), body, bom=False, crlf=crlf))
    return path


def write_portal(
    path: Path, rows: list[dict], locations: list[str] | str = "us-101", quirks: bool = True
) -> Path:
    """Combined portal CSV; with quirks: BOM, CRLF and quoted thousands separators."""
    names = [locations] * len(rows) if isinstance(locations, str) else locations
    canonical = [name.lower() for name in ns.PORTAL_HEADER]
    body = [
        [name if c == s.LOCATION else _text(r.get(c), quirks) for c in canonical]
        for r, name in zip(rows, names, strict=True)
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(_csv_bytes(list(ns.PORTAL_HEADER), body, bom=quirks, crlf=quirks))
    return path


@pytest.fixture
def two_vehicle_rows() -> list[dict[str, float]]:
    """Two vehicles of us-101 0750am, frames 10..39, straight along +y in lanes 1 and 2."""
    return straight_track(1, range(10, 40), x_ft=6.0, lane_id=1) + straight_track(
        2, range(10, 40), x_ft=18.0, speed_fps=40.0
    )


def set_budget(monkeypatch: pytest.MonkeyPatch, **sizes: int) -> None:
    """Build in smaller pieces than the engine's own (`budget.BUDGET`): tests cut a tiny build
    into many, whose outputs must be those of one piece."""
    monkeypatch.setattr(budget, "BUDGET", replace(budget.BUDGET, **sizes))
