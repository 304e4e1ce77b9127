"""The speed check's medians: streamed, and exactly Polars' own."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from conftest import set_budget

from ngsim_graphs.sources import speeds
from ngsim_graphs.sources.speeds import speed_medians

FT = 0.3048


def sample_values(kind: str, rng: np.random.Generator, n: int) -> np.ndarray:
    if kind == "normal":
        return rng.normal(0, 1, n)
    if kind == "few values":
        return rng.integers(0, 4, n).astype(float)
    if kind == "wide":
        return np.exp(rng.normal(0, 20, n))
    if kind == "huge":
        return rng.uniform(-1e300, 1e300, n)
    return np.round(rng.normal(30, 10, n), 2)  # feet per second, as NGSIM writes them


@pytest.mark.parametrize("kind", ["normal", "few values", "wide", "huge", "cents"])
def test_a_streamed_median_is_polars_median_exactly(
    kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Against Polars' median of all the values at once, to the bit: even and odd counts, many
    equal values, ranges of 1e-40 to 1e40 and of 2e300 (no bins narrow it), with at most 50
    values held and histograms of 8 bins (the narrowing runs many rounds)."""
    set_budget(monkeypatch, median_held_values=50)
    set_budget(monkeypatch, median_bins=8)
    rng = np.random.default_rng(len(kind))
    for n in [1, 2, 3, 51, 400, 1_001, 2_000]:
        column = pl.Series("x", sample_values(kind, rng, n))
        assert speeds.streamed_median(column.to_frame().lazy()) == column.median()


def test_a_streamed_median_leaves_nulls_out_and_takes_nan_and_float32_as_polars_does() -> None:
    frame = pl.DataFrame({"x": [3.0, None, 1.0, None, 2.0, 10.0]})
    assert speeds.streamed_median(frame.lazy()) == 2.5
    assert (
        speeds.streamed_median(pl.DataFrame({"x": [None, None]}, schema={"x": pl.Float64}).lazy())
        is None
    )
    single = pl.Series("x", np.random.default_rng(3).normal(0, 1, 1_000), dtype=pl.Float32)
    assert speeds.streamed_median(single.to_frame().lazy()) == single.median()
    with_nan = pl.DataFrame({"x": [3.0, float("nan"), 1.0]})
    assert speeds.streamed_median(with_nan.lazy()) == with_nan["x"].median() == 3.0


def test_speed_medians_of_a_lazy_table_are_polars_medians() -> None:
    rng = np.random.default_rng(9)
    compared = pl.DataFrame({"shown": rng.uniform(0, 90, 3_001), "vel": rng.uniform(0, 90, 3_001)})
    mismatch, shown, rows = speed_medians(compared.lazy(), FT)
    expected = (compared["vel"] - compared["shown"]).abs().median()
    assert (mismatch, shown, rows) == (
        expected * FT,
        compared["shown"].median() * FT,
        3_001,
    )
