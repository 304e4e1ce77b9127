"""What a raw row of a source may hold: its physical limits (`Source.limits`).

Each source says its own: the limits are metric, but its frame numbers are its own frames (NGSIM
10 Hz, highD 25 Hz), so `max_frame_id` is a source's and has no default. A build applies its
source's limits (or others given to `pipeline.run_build`) and its manifest records the limits it
applied beside its config (docs/build-format.md); the build config holds none.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True, kw_only=True)
class PhysicalLimits:
    """What a raw row may hold; rows beyond a limit are dropped and counted per reason
    (docs/trust.md).

    Generous for highway traffic: real NGSIM rows stay far inside them (v_Acc within 3.4 m/s²,
    speeds under 40 m/s, study areas under 1 km long), so a row beyond one is a damaged value, a
    swapped column or another unit, never a driver.
    """

    max_speed_mps: float = 70.0  # 252 km/h; below 0 is beyond it too
    max_abs_accel_mps2: float = 15.0  # 1.5 g
    max_abs_position_m: float = 5_000.0  # |x| and |y| (NGSIM: Local_X and Local_Y)
    max_jump_m: float = 10.0  # between two consecutive frames of a vehicle (NGSIM: 100 m/s)
    max_outlier_frames: int = 10  # a displaced burst this long or shorter is dropped
    max_frame_id: int  # in the source's own frames; the first frame is 0
    # Vehicle sizes above 0 and up to these (NGSIM's longest trucks are about 23 m, 2.6 m wide).
    max_vehicle_length_m: float = 40.0
    max_vehicle_width_m: float = 5.0
    # Lane numbers from 0 up to this: NGSIM's arterials number turn bays and intersections too.
    max_lane_id: int = 255
    # The speed column must agree with the motion the positions show over 1 s: the median
    # difference may be at most this plus this share of the median speed, or the speed column is
    # not a speed (swapped with the acceleration, another unit).
    max_speed_mismatch_mps: float = 1.0
    max_speed_mismatch_share: float = 0.25
    # A file (or recording) with a larger share of stray or implausible rows is not used at all:
    # so many bad rows say the file is damaged or its columns are not what they claim to be.
    max_dropped_share: float = 0.01

    def __post_init__(self) -> None:
        positive = (
            self.max_speed_mps,
            self.max_abs_accel_mps2,
            self.max_abs_position_m,
            self.max_jump_m,
            self.max_vehicle_length_m,
            self.max_vehicle_width_m,
        )
        whole = (self.max_frame_id, self.max_outlier_frames, self.max_lane_id)
        if min(positive) <= 0 or min(whole) < 1:
            raise ValueError("physical limits must be positive")
        if not 0 <= self.max_dropped_share <= 1:
            raise ValueError("max_dropped_share must be in [0, 1]")

    def to_dict(self) -> dict[str, Any]:
        """The limits as the manifest records them (`from_dict` reads them back)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> PhysicalLimits:
        """The limits a manifest records; ValueError for a limit this version does not know."""
        unknown = sorted(set(values) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(f"unknown physical limits {unknown}: made by a newer ngsim-graphs?")
        return cls(**values)
