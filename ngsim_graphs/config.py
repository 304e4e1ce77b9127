"""Frozen configuration dataclasses, one per program. Field names carry their units."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

from ngsim_graphs.schema import Protocol, RawFormat, SplitMode

DEFAULT_EDGE_TYPES = ("spatial", "temporal")  # the paper's: what a build of no edge_types has


@dataclass(frozen=True)
class PhysicalLimits:
    """What a raw row may hold; rows beyond a limit are dropped and counted per reason
    (docs/trust.md).

    Generous for highway traffic: real NGSIM rows stay far inside them (v_Acc within 3.4 m/s²,
    speeds under 40 m/s, study areas under 1 km long), so a row beyond one is a damaged value, a
    swapped column or another unit, never a driver.
    """

    max_speed_mps: float = 70.0  # 252 km/h; below 0 is beyond it too
    max_abs_accel_mps2: float = 15.0  # 1.5 g
    max_abs_position_m: float = 5_000.0  # |Local_X| and |Local_Y|
    max_jump_m: float = 10.0  # between two consecutive 0.1 s frames of a vehicle: 100 m/s
    max_outlier_frames: int = 10  # a displaced burst this long or shorter is dropped (1 s)
    max_frame_id: int = 72_000  # two hours at 10 Hz; the first frame is 0
    # Vehicle sizes above 0 and up to these (NGSIM's longest trucks are about 23 m, 2.6 m wide).
    max_vehicle_length_m: float = 40.0
    max_vehicle_width_m: float = 5.0
    # Lane numbers from 0 up to this: NGSIM's arterials number turn bays and intersections too.
    max_lane_id: int = 255
    # v_Vel must agree with the motion the positions show over 1 s: the median difference may be
    # at most this plus this share of the median speed, or the speed column is not a speed in
    # feet per second (swapped with v_Acc, another unit).
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


@dataclass(frozen=True)
class BuildConfig:
    """Everything that shapes a build's output. The CLI builds it; the library only reads it."""

    locations: tuple[str, ...] = ("us-101", "i-80")
    time_step_s: float = 0.2  # the resampled grid: a whole number of each source's frames
    heading_smoothing_s: float = 1.0  # centred moving average of positions before atan2
    min_heading_speed_mps: float = 2.0  # below this the last heading is held
    history_steps: int = 16  # K_H: 3 s of history including the present
    future_steps: int = 25  # K_F: 5 s to predict
    stride_s: float = 8.0  # between window starts of one ego track (8 s: non-overlapping)
    d_sense_m: float = 50.0  # a vehicle this close to the ego at a history step is a node
    d_min_m: float = 25.0  # two actor nodes this close share spatial edges
    split: SplitMode = SplitMode.VEHICLE
    split_fractions: tuple[float, float, float] = (0.7, 0.1, 0.2)  # train, validation, test
    seed: int = 0  # for the random split
    ego_is_target: bool = False  # whether the ego is predicted too (the aigem protocol)
    limits: PhysicalLimits = PhysicalLimits()
    # aigem: ego windows at a stride; cs-lstm: CS-LSTM's kept rows, the ego the only target
    protocol: Protocol = Protocol.AIGEM
    # The graphs' edge types, by name (`edges.EDGE_TYPES` knows them: `edges.types_of`); the
    # count columns, the statistics and the model's GATs follow them, in this order.
    edge_types: tuple[str, ...] = DEFAULT_EDGE_TYPES

    def __post_init__(self) -> None:
        # Which names are locations is the sources' to say (`sources.registry.check_locations`).
        if not self.locations:
            raise ValueError("locations must name at least one location")
        # Whether the grid is whole frames is the source's to say (`Source.frames_per_step`).
        if self.time_step_s <= 0:
            raise ValueError("time_step_s must be > 0")
        if self.heading_smoothing_s < 0 or self.min_heading_speed_mps < 0:
            raise ValueError("heading_smoothing_s and min_heading_speed_mps must be >= 0")
        stride = self.stride_s / self.time_step_s
        if stride < 1 - 1e-9 or abs(stride - round(stride)) > 1e-6:
            raise ValueError(
                f"stride_s must be a positive multiple of time_step_s ({self.time_step_s} s)"
            )
        if self.history_steps < 2 or self.future_steps < 1:
            raise ValueError("history_steps must be >= 2 and future_steps >= 1")
        if self.d_sense_m <= 0 or self.d_min_m < 0:
            raise ValueError("d_sense_m must be > 0 and d_min_m >= 0")
        fractions = self.split_fractions
        if len(fractions) != 3 or min(fractions) < 0 or abs(sum(fractions) - 1) > 1e-9:
            raise ValueError("split_fractions must be three non-negative numbers summing to 1")
        if not self.edge_types or len(set(self.edge_types)) != len(self.edge_types):
            raise ValueError("edge_types must name at least one edge type, each once")
        if self.protocol is Protocol.CS_LSTM:
            self._check_cslstm()

    def _check_cslstm(self) -> None:
        """The settings that have no meaning under the cs-lstm protocol stay at their defaults:
        its samples are the script's kept rows, split by the script's rule, the ego the target."""
        default = BuildConfig()
        unused = [
            f"{name} {getattr(value, 'value', value)}"
            for name in ("split", "stride_s", "split_fractions", "ego_is_target")
            if (value := getattr(self, name)) != getattr(default, name)
        ]
        if unused:
            verb = "has" if len(unused) == 1 else "have"
            raise ValueError(
                f"{', '.join(unused)}: {verb} no meaning under the cs-lstm protocol, whose "
                "samples are CS-LSTM's kept rows, one per row, split by the script's vehicle rule "
                "(70/10/20), the row's vehicle the only target"
            )

    @property
    def stride_steps(self) -> int:
        """Grid steps between the starts of two windows of one ego track (40 for 8 s)."""
        return round(self.stride_s / self.time_step_s)

    @property
    def window_steps(self) -> int:
        """Grid steps of one window: history (with the present) and future (41)."""
        return self.history_steps + self.future_steps

    @property
    def smoothing_window_steps(self) -> int:
        """Odd window length, in grid steps, of the centred moving average (5 for 1 s at 0.2 s)."""
        steps = max(1, round(self.heading_smoothing_s / self.time_step_s))
        return steps if steps % 2 == 1 else steps + 1

    def to_dict(self) -> dict[str, Any]:
        """The settings as the manifest records them. The paper's edge types are left out, as
        builds made before edge_types were recorded left them: a default build's config, and so
        its config hash, stay what they were (`from_dict` reads their absence as the default)."""
        values = asdict(self)
        if self.edge_types == DEFAULT_EDGE_TYPES:
            del values["edge_types"]
        return values

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> BuildConfig:
        """The config of a manifest (JSON lists back to tuples, the split back to its enum); a
        manifest without edge_types (the paper's, or a build older than the setting) has the
        default's."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown build settings {unknown}: made by a newer ngsim-graphs?")
        typed = dict(values)
        for name in ("locations", "split_fractions", "edge_types"):
            if name in typed:
                typed[name] = tuple(typed[name])
        if "split" in typed:
            typed["split"] = SplitMode(typed["split"])
        if "protocol" in typed:
            typed["protocol"] = Protocol(typed["protocol"])
        if "limits" in typed:
            typed["limits"] = PhysicalLimits(**typed["limits"])
        return cls(**typed)


@dataclass(frozen=True)
class SynthConfig:
    """What `ngsim-graphs synth` generates: NGSIM-shaped data, seeded and deterministic."""

    raw_format: RawFormat = RawFormat.TXT
    recordings: int = 6  # 1..6, taken in order from the six official (location, period) pairs
    minutes: float = 15.0  # length of each recording
    seed: int = 0
    quirks: bool = False  # inject the format quirks of real exports (docs/conventions.md)

    def __post_init__(self) -> None:
        if not 1 <= self.recordings <= 6:
            raise ValueError("recordings must be between 1 and 6 (the six NGSIM periods)")
        if not 0 < self.minutes <= 60:
            raise ValueError("minutes must be in (0, 60]")
