"""Frozen configuration dataclasses, one per program. Field names carry their units."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from ngsim_graphs.recordings import KNOWN_LOCATION_NAMES
from ngsim_graphs.schema import RawFormat

FRAME_STEP_S = 0.1  # NGSIM's 10 Hz frame period


@dataclass(frozen=True)
class BuildConfig:
    """Everything that shapes a build's output. The CLI builds it; the library only reads it."""

    locations: tuple[str, ...] = ("us-101", "i-80")
    time_step_s: float = 0.2  # the resampled grid: frames with frame_id % 2 == 0
    heading_smoothing_s: float = 1.0  # centred moving average of positions before atan2
    min_heading_speed_mps: float = 2.0  # below this the last heading is held

    def __post_init__(self) -> None:
        unknown = sorted(set(self.locations) - set(KNOWN_LOCATION_NAMES))
        if unknown or not self.locations:
            raise ValueError(
                f"unknown location(s) {unknown}; choose from {', '.join(KNOWN_LOCATION_NAMES)}"
            )
        if self.frames_per_step < 1 or abs(self.frames_per_step * FRAME_STEP_S - self.time_step_s) > 1e-9:
            raise ValueError(f"time_step_s must be a positive multiple of {FRAME_STEP_S} s")
        if self.heading_smoothing_s < 0 or self.min_heading_speed_mps < 0:
            raise ValueError("heading_smoothing_s and min_heading_speed_mps must be >= 0")

    @property
    def frames_per_step(self) -> int:
        """NGSIM frames per grid step (2 for 0.2 s)."""
        return round(self.time_step_s / FRAME_STEP_S)

    @property
    def smoothing_window_steps(self) -> int:
        """Odd window length, in grid steps, of the centred moving average (5 for 1 s at 0.2 s)."""
        steps = max(1, round(self.heading_smoothing_s / self.time_step_s))
        return steps if steps % 2 == 1 else steps + 1

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class SynthConfig:
    """What `ngsim-graphs synth` generates: NGSIM-shaped data, seeded and deterministic."""

    raw_format: RawFormat = RawFormat.TXT
    recordings: int = 6  # 1..6, taken in order from the six official (location, period) pairs
    minutes: float = 15.0  # length of each recording
    seed: int = 0
    quirks: bool = False  # inject the format quirks of real exports (SPEC section 1)

    def __post_init__(self) -> None:
        if not 1 <= self.recordings <= 6:
            raise ValueError("recordings must be between 1 and 6 (the six NGSIM periods)")
        if not 0 < self.minutes <= 60:
            raise ValueError("minutes must be in (0, 60]")
