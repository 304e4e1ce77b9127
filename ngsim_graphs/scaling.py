"""MinMax scaling fitted on the train split only (docs/conventions.md): one type, both directions.

x, y and heading map to (-1, 1); speed and the scaled edge attributes (the spatial edges'
distance) to (0, 1); an edge type that is not `scaled` (temporal: t_s) keeps its attribute. Stored
values stay physical: the build fits a `MinMaxScaler` with `train_ranges` (from the neighbourhoods
of the train samples' ego rows, which the edge types' rules count: the same minima and maxima as
`widened` over every train graph gives), the manifest records its `to_dict`, and the dataset reads
it back (`from_dict`) and applies it. `scale` and `unscale` are plain arithmetic with Python floats,
so they take numpy arrays and torch tensors alike (a tensor keeps its dtype, device and graph).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from ngsim_graphs import edges
from ngsim_graphs.grid import STATE_COLUMNS, RecordingArrays
from ngsim_graphs.neighbourhoods import Neighbourhoods, positions, ranged, sample_chunks

FEATURES = STATE_COLUMNS  # node feature columns, in order
SCALED = FEATURES + edges.scaled_attributes()  # the quantities, in order: the manifest's
TARGET_RANGES: Mapping[str, tuple[float, float]] = {
    "x_m": (-1.0, 1.0),
    "y_m": (-1.0, 1.0),
    "heading_rad": (-1.0, 1.0),
    "speed_mps": (0.0, 1.0),
    "distance_m": (0.0, 1.0),
}

Values = TypeVar("Values")  # np.ndarray or torch.Tensor (anything with float arithmetic)


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


@dataclass(frozen=True)
class MinMaxScaler:
    """Observed minimum and maximum of each quantity of SCALED (physical units: m, rad, m/s),
    and the range each maps onto. `low` is inf and `high` -inf where nothing was observed (an
    empty train split): such a scaler is not `is_fitted` and cannot be applied."""

    low: Mapping[str, float]
    high: Mapping[str, float]
    target: Mapping[str, tuple[float, float]] = field(default_factory=lambda: dict(TARGET_RANGES))

    @classmethod
    def empty(cls) -> MinMaxScaler:
        """Nothing observed yet: `widened` by each train graph in turn."""
        return cls(dict.fromkeys(SCALED, math.inf), dict.fromkeys(SCALED, -math.inf))

    def widened(
        self, node_features: np.ndarray, attributes: Mapping[str, np.ndarray]
    ) -> MinMaxScaler:
        """Widened by (N, 4) node features (FEATURES order) and (E,) edge attributes by the name
        of the scaled quantity (an edge type's `attribute`: "distance_m")."""
        low, high = dict(self.low), dict(self.high)
        columns = [(name, node_features[:, i]) for i, name in enumerate(FEATURES)]
        for name, column in [*columns, *attributes.items()]:
            if len(column):
                low[name] = min(low[name], float(column.min()))
                high[name] = max(high[name], float(column.max()))
        return MinMaxScaler(low, high, self.target)

    def joined(self, other: MinMaxScaler) -> MinMaxScaler:
        """Widened by everything `other` observed (the target ranges stay this scaler's)."""
        low = {name: min(self.low[name], other.low[name]) for name in SCALED}
        high = {name: max(self.high[name], other.high[name]) for name in SCALED}
        return MinMaxScaler(low, high, self.target)

    @property
    def is_fitted(self) -> bool:
        """Whether every quantity has a finite minimum, maximum and target range (it can be
        applied)."""
        bounds = [(self.low[n], self.high[n], *self.target[n]) for n in SCALED]
        return all(math.isfinite(v) for values in bounds for v in values)

    def scale(self, name: str, values: Values) -> Values:
        """Physical values of quantity `name` (any shape) -> scaled: [min, max] maps linearly
        onto its target range; a constant quantity maps to the target's low end (finite values)."""
        low, (to_low, to_high) = self.low[name], self.target[name]
        span = self.high[name] - low
        unit = (values - low) / span if span > 0 else values * 0.0  # type: ignore[operator]
        return to_low + unit * (to_high - to_low)  # type: ignore[return-value]

    def unscale(self, name: str, values: Values) -> Values:
        """Scaled values of quantity `name` (any shape) -> physical units; `scale`'s inverse (a
        constant quantity comes back as its one value). Differentiable for tensors."""
        (to_low, to_high), low = self.target[name], self.low[name]
        span = (self.high[name] - low) / (to_high - to_low)
        return (values - to_low) * span + low  # type: ignore[operator,return-value]

    def scale_features(self, node_features: np.ndarray) -> np.ndarray:
        """(N, 4) physical [x, y, heading, speed] -> (N, 4) scaled float32."""
        columns = [self.scale(name, node_features[:, i]) for i, name in enumerate(FEATURES)]
        return np.stack(columns, axis=1).astype(np.float32)

    def scale_edges(self, edge: edges.EdgeType, attribute: np.ndarray) -> np.ndarray:
        """(E,) physical attributes of edges of type `edge` -> (E, 1) float32, scaled where
        the edge type's attribute is (`edge.scaled`)."""
        values = self.scale(edge.attribute, attribute) if edge.scaled else attribute
        return np.asarray(values, dtype=np.float32)[:, None]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, as the manifest records it: {name: {"min", "max", "to"}} in SCALED order;
        min and max are null where not finite (nothing observed)."""
        return {
            name: {
                "min": _finite(self.low[name]),
                "max": _finite(self.high[name]),
                "to": list(self.target[name]),
            }
            for name in SCALED
        }

    @classmethod
    def from_dict(cls, values: object) -> MinMaxScaler:
        """`to_dict`'s form back (a null min or max: nothing observed); ValueError for any other
        form: a quantity missing, a value that is not a number, a target that is not two."""
        if not isinstance(values, Mapping):
            raise ValueError("the scaler is not a mapping")
        low, high, target = {}, {}, {}
        for name in SCALED:
            entry = values.get(name)
            if not isinstance(entry, Mapping):
                raise ValueError(f"the scaler has no {name}")
            bounds, to = (entry.get("min"), entry.get("max")), entry.get("to")
            if not all(v is None or _number(v) for v in bounds):
                raise ValueError(f"the scaler's {name} min or max is not a number")
            if not isinstance(to, list | tuple) or len(to) != 2 or not all(map(_number, to)):
                raise ValueError(f"the scaler's {name} target range is not two numbers")
            low[name] = math.inf if bounds[0] is None else bounds[0]
            high[name] = -math.inf if bounds[1] is None else bounds[1]
            target[name] = (to[0], to[1])
        return cls(low, high, target)


def train_ranges(
    rec: RecordingArrays, hood: Neighbourhoods, history: np.ndarray, is_train: np.ndarray
) -> MinMaxScaler:
    """The minima and maxima of SCALED over the graphs of the train samples (`is_train`, (B,)
    bool) as a scaler: x and y in each sample's frame, with its present ego at (0, 0); the edge
    attributes as the edge types' rules counted them in `hood`.

    Only the rows `hood` holds count: the scalers of the neighbourhoods of consecutive ranges of
    steps, joined, are that of all at once (a minimum of minima; the ego's frame is a
    subtraction, which rounds monotonically)."""
    if len(hood.rows) == 0:
        return MinMaxScaler.empty()
    low, high = dict.fromkeys(SCALED, np.inf), dict.fromkeys(SCALED, -np.inf)
    used = np.zeros(len(hood.rows), bool)
    train = np.flatnonzero(is_train)
    for part in sample_chunks(len(train)):
        rows = history[train[part]]
        present, at = positions(hood, rows)
        origin = np.take(rec.node_state, rows[:, -1], axis=0)
        for i, name in enumerate(SCALED[:2]):
            sample_low = np.where(present, hood.low[at, i], np.inf).min(axis=1)
            sample_high = np.where(present, hood.high[at, i], -np.inf).max(axis=1)
            low[name] = min(low[name], (sample_low - origin[:, i]).min())
            high[name] = max(high[name], (sample_high - origin[:, i]).max())
        used[at[present]] = True
    columns = ranged()  # hood.low's and hood.high's, by name
    for name in SCALED[2:]:
        i = columns.index(name)
        low[name] = hood.low[used, i].min(initial=np.inf)
        high[name] = hood.high[used, i].max(initial=-np.inf)
    return MinMaxScaler(
        {n: float(v) for n, v in low.items()}, {n: float(v) for n, v in high.items()}
    )
