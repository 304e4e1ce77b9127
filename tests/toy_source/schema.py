"""The toy format's raw columns: `<anything>.toy`, semicolon-separated with a header, one
recording of road "toy-road" at 25 Hz; positions in metres along (`s_m`) and across (`d_m`) the
road, the speed in km/h. No logic lives here."""

from __future__ import annotations

from typing import Final

import polars as pl

FRAME: Final = "frame"  # 25 Hz: 0.04 s a frame, the first 0
CAR: Final = "car"  # the vehicle's id; 0 means "no car" (a placeholder row)
S_M: Final = "s_m"  # along the direction of travel
D_M: Final = "d_m"  # across it
SPEED_KMH: Final = "speed_kmh"

RAW_SCHEMA: Final = pl.Schema(
    {FRAME: pl.Int32, CAR: pl.Int32, S_M: pl.Float64, D_M: pl.Float64, SPEED_KMH: pl.Float64}
)
SEPARATOR: Final = ";"
