"""Frozen configuration dataclasses, one per program. Field names carry their units."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from numbers import Integral
from typing import Any

from ngsim_graphs.integrity import LIMITS_KEY
from ngsim_graphs.schema import Protocol, RawFormat, SplitMode

DEFAULT_EDGE_TYPES = ("spatial", "temporal")  # the paper's: what a build of no edge_types has
MAX_SEED = 2**32 - 1  # NumPy's and PyTorch's seeds lie in [0, 2**32 - 1]
# The most threads or worker processes an option may ask for (--threads, --workers, --jobs): more
# than the largest machines' cores (some 800 hardware threads), far below what would fill the
# process table or overflow the C int of torch.set_num_threads. Fixed, not the cores of this
# machine: a run records its settings, and another machine reads them back.
MAX_PARALLEL = 1024


# The checks of every numeric setting, in one place: a config's __post_init__ calls them, so that
# the library refuses what the command line refuses (the CLI turns the ValueError into one line
# naming the option). NaN compares false with everything and infinity passes `> 0`, so a bound
# alone lets them through: each check asks for a finite number first.


def check_at_least(name: str, value: float, low: float) -> None:
    """ValueError unless `value` is a finite number >= `low`."""
    if not (math.isfinite(value) and value >= low):
        raise ValueError(f"{name} must be a finite number >= {low:g}, not {value:g}")


def check_above(name: str, value: float, low: float) -> None:
    """ValueError unless `value` is a finite number > `low`."""
    if not (math.isfinite(value) and value > low):
        raise ValueError(f"{name} must be a finite number > {low:g}, not {value:g}")


def check_count(name: str, value: int, low: int, high: int | None = None) -> None:
    """ValueError unless the whole number `value` is >= `low` and, where given, <= `high`."""
    if value < low:
        raise ValueError(f"{name} must be >= {low}")
    if high is not None and value > high:
        raise ValueError(f"{name} must be <= {high}")


def check_seed(name: str, seed: int) -> None:
    """ValueError unless `seed` is a whole number in [0, MAX_SEED] (NumPy's and PyTorch's)."""
    if not (isinstance(seed, Integral) and 0 <= seed <= MAX_SEED):
        raise ValueError(
            f"{name} must be a whole number from 0 to {MAX_SEED} (2**32 - 1), not {seed}"
        )


def whole_steps(duration_s: float, time_step_s: float) -> bool:
    """Whether `duration_s` is a positive whole number of `time_step_s` steps (8 s of 0.2 s: 40),
    within float rounding (0.6 / 0.2 is 2.9999999999999996); never NaN or infinity."""
    steps = duration_s / time_step_s
    return math.isfinite(steps) and steps > 1 - 1e-9 and abs(steps - round(steps)) <= 1e-6


@dataclass(frozen=True)
class BuildConfig:
    """The grid and the graph rules of a build. The CLI builds it; the library only reads it.

    What a raw row may hold is its source's (`Source.limits`), not the build config's."""

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
        check_above("time_step_s", self.time_step_s, 0)
        check_at_least("heading_smoothing_s", self.heading_smoothing_s, 0)
        check_at_least("min_heading_speed_mps", self.min_heading_speed_mps, 0)
        if not whole_steps(self.stride_s, self.time_step_s):
            raise ValueError(
                f"stride_s must be a positive multiple of time_step_s ({self.time_step_s} s)"
            )
        if self.history_steps < 2 or self.future_steps < 1:
            raise ValueError("history_steps must be >= 2 and future_steps >= 1")
        check_above("d_sense_m", self.d_sense_m, 0)
        check_at_least("d_min_m", self.d_min_m, 0)
        check_seed("seed", self.seed)
        fractions = self.split_fractions
        if (
            len(fractions) != 3
            or not all(math.isfinite(f) and f >= 0 for f in fractions)
            or abs(sum(fractions) - 1) > 1e-9
        ):
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
        default's.

        The adapter for older builds: their manifests (and the runs made of them) recorded the
        source's physical limits inside the config (under LIMITS_KEY, where a manifest now
        records them beside it); they are set aside here, and `Manifest.from_dict` reads them as
        the limits that build applied."""
        known = {f.name for f in fields(cls)}
        values = {k: v for k, v in values.items() if k != LIMITS_KEY}
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
        check_seed("seed", self.seed)
