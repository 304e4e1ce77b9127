"""MinMax scaling fitted on the train split only (SPEC section 3).

x, y and heading map to (-1, 1); speed and spatial-edge distance to (0, 1); the temporal-edge
attribute (t_s) is not scaled. Stored values stay physical: the fitted ranges go into the
manifest and the dataset applies them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


FEATURES = ("x_m", "y_m", "heading_rad", "speed_mps")  # node feature columns, in order
TARGET_RANGES = {"x_m": (-1.0, 1.0), "y_m": (-1.0, 1.0), "heading_rad": (-1.0, 1.0),
                 "speed_mps": (0.0, 1.0), "distance_m": (0.0, 1.0)}  # fmt: skip


@dataclass(frozen=True)
class FittedRanges:
    """Observed minimum and maximum of each scaled quantity, in physical units."""

    low: dict[str, float]
    high: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: min and max are null when the train split is empty."""
        finite = lambda v: v if math.isfinite(v) else None  # noqa: E731
        return {
            name: {"min": finite(self.low[name]), "max": finite(self.high[name]), "to": list(TARGET_RANGES[name])}
            for name in TARGET_RANGES
        }


def empty_ranges() -> FittedRanges:
    return FittedRanges({n: float("inf") for n in TARGET_RANGES}, {n: float("-inf") for n in TARGET_RANGES})


def update_ranges(ranges: FittedRanges, node_features: np.ndarray, distances_m: np.ndarray) -> FittedRanges:
    """Widen `ranges` by (N, 4) node features (FEATURES order) and (E,) spatial-edge distances."""
    low, high = dict(ranges.low), dict(ranges.high)
    values = {name: node_features[:, i] for i, name in enumerate(FEATURES)}
    values["distance_m"] = distances_m
    for name, column in values.items():
        if len(column):
            low[name] = min(low[name], float(column.min()))
            high[name] = max(high[name], float(column.max()))
    return FittedRanges(low, high)


def scale(values: np.ndarray, fitted: dict[str, float], target: tuple[float, float]) -> np.ndarray:
    """Map [min, max] of `fitted` linearly onto `target`; a constant quantity maps to its low end."""
    span = fitted["max"] - fitted["min"]
    unit = (values - fitted["min"]) / span if span > 0 else np.zeros_like(values)
    return target[0] + unit * (target[1] - target[0])
