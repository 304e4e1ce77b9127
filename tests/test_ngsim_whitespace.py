"""The whitespace text's fast path (Polars' CSV reader on single-spaced lines) against the general
reader (each line split on runs of whitespace by a regex): the same rows, or None and the general
reader's own."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from conftest import set_budget

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.ngsim import files, whitespace
from ngsim_graphs.sources.ngsim import schema as ns

INTEGERS = [c for c in ns.TXT_COLUMNS if ns.RAW_SCHEMA[c] != pl.Float64]


def _value(rng: random.Random, column: str) -> str:
    """A value of `column` as a file may write it: widths, signs, points, zeros in front."""
    if ns.RAW_SCHEMA[column] != pl.Float64:
        value = rng.choice([0, 1, 2, 3, rng.randrange(1, 3000), rng.randrange(10**12, 2 * 10**12)])
        if column != ns.GLOBAL_TIME:
            value %= 100
        return rng.choice([f"{value}", f"{value:06d}", f"-{value}" if value else "0"])
    value = rng.uniform(-5000, 5000) if rng.random() < 0.5 else rng.uniform(0, 50)
    return rng.choice(
        [f"{value:.3f}", f"{value:.2f}", f"{value}", f"{value:.0f}.", f"{abs(value) % 1:.4f}"[1:],
         f"{value:.6f}", "0", "-0.0", "9999.99"]
    )  # fmt: skip


def _line(rng: random.Random, indent: tuple[int, int]) -> str:
    """A line of 18 values, `indent` (fewest, most) spaces before its first."""
    fields = [_value(rng, column) for column in ns.TXT_COLUMNS]
    widths = [rng.randint(*indent), *(rng.randint(1, 6) for _ in fields[1:])]
    return "".join(f"{' ' * w}{f}" for w, f in zip(widths, fields, strict=True)) + (
        " " * rng.randint(0, 3)
    )


def _general(monkeypatch: pytest.MonkeyPatch, path: Path, scratch: Path) -> pl.DataFrame:
    """The rows the general reader alone makes of `path`."""
    monkeypatch.setattr(files, "parse_plain", lambda *_: None)
    try:
        return files.read_raw_file(path, ("us-101",), scratch).frame.collect()
    finally:
        monkeypatch.undo()


def _both(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, text: str) -> tuple:
    """(fast, general): each reader's rows of `text` (or the error it raised), in small chunks."""
    set_budget(monkeypatch, text_chunk_bytes=4096)
    path = tmp_path / "trajectories-0750am-0805am.txt"
    path.write_bytes(text.encode())
    results = []
    for fast in (True, False):
        try:
            if fast:
                rows = files.read_raw_file(path, ("us-101",), tmp_path / "a").frame.collect()
            else:
                set_budget(monkeypatch, text_chunk_bytes=4096)
                rows = _general(monkeypatch, path, tmp_path / "b")
            results.append(rows)
        except NgsimInputError as err:
            results.append(str(err))
    return tuple(results)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("indent", [(0, 6), (1, 6), (0, 0)])  # some lines, all, none
def test_random_plain_text_reads_as_the_general_reader_reads_it(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, seed: int, indent: tuple[int, int]
) -> None:
    rng = random.Random(seed)
    lines = [_line(rng, indent) for _ in range(300)]
    ends = rng.choice(["\n", "\r\n"])
    text = ends.join(lines) + rng.choice([ends, ""])
    chunks = []
    real = whitespace.parse_plain
    monkeypatch.setattr(
        files, "parse_plain", lambda *a: chunks.append(real(*a) is not None) or real(*a)
    )
    fast, general = _both(monkeypatch, tmp_path, text)
    assert chunks and all(chunks)  # every chunk took the fast path
    assert isinstance(fast, pl.DataFrame)
    assert fast.equals(general)


QUIRKS = [
    "1 0 1 1113433184300 7 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # plain
    "   \n",  # a blank line
    "1 0 1 1113433184300 7 2 3 4 5 6 2 7 8 1 0 5 0.00\n",  # a field short
    "1 0 1 1113433184300 7 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99 3\n",  # a field too many
    "1 0 1 1113433184300 1e2 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # an exponent
    "1 0 1 1113433184300 +7 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # a plus sign
    "1 0.0 1 1113433184300 7 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # a whole number with a point
    "1 0.5 1 1113433184300 7 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # a fraction in an integer
    "1 0 1 1113433184300 1,156 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # thousands
    "1 0 1 1113433184300 1,2 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # a decimal comma
    "1 0 1 1113433184300 nan 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # not finite
    "1 0 1 1113433184300 - 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # a minus alone
    "1 0 1 1113433184300 1.2.3 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # two points
    "1 0 1 1113433184300 1-2 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # a minus inside
    "1 0 1 1113433184300 .5 -.5 5. -0 2 6 2 7 8 1 0 5 0.00 9999.99\n",  # short floats
    "1 0 1 9007199254740993 7 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # beyond 2**53
    "99999999999 0 1 1113433184300 7 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # beyond Int32
    "1 0 1 1113433184300 7 2 3 4 5 6 300 7 8 1 0 5 0.00 9999.99\n",  # beyond Int8
    "1\t0 1 1113433184300 7 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # a tab
    "1 0 1 1113433184300 7 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\r\n",  # CRLF
    "1 0 1 1113433184300 7\r2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # a lone CR
    "1 0 1 1113433184300 7\xa02 3 4 5 6 2 7 8 1 0 5 0.00 9999.99\n",  # a no-break space
    "1 0 1 1113433184300 7 2 3 4 5 6 2 7 8 1 0 5 0.00 99999999999999999999\n",  # long float
]


@pytest.mark.parametrize("quirk", range(len(QUIRKS)))
def test_a_quirky_line_reads_as_the_general_reader_reads_it(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, quirk: int
) -> None:
    plain = QUIRKS[0]
    text = plain * 40 + QUIRKS[quirk] + plain * 40
    fast, general = _both(monkeypatch, tmp_path, text)
    if isinstance(general, str):
        assert fast == general  # the same error, naming the same line
    else:
        assert isinstance(fast, pl.DataFrame) and fast.equals(general)


def test_single_spaced_keeps_one_space_between_fields_and_none_at_the_ends() -> None:
    assert whitespace.single_spaced(b"   1  22 3   \n4 5\n  \n 6\n", 4) == (
        b"1 22 3\n4 5\n\n6\n",
        False,
    )
    # Every line indented: one space left before each, read as an empty first field.
    assert whitespace.single_spaced(b"   1  22 3   \n 4 5\n  6", 2) == (b" 1 22 3\n 4 5\n 6", True)
    assert whitespace.single_spaced(b"1\t 2\r\n", 1) == (b"1 2\n", False)


def test_only_plain_text_is_plain() -> None:
    assert whitespace.is_plain(b" 1 -2.5\t3\r\n")
    assert not whitespace.is_plain(b"1 2\r3\n")  # a CR that ends no line
    assert not whitespace.is_plain(b"1 2e3\n")
    assert not whitespace.is_plain("1 2\xa0\n".encode())


def test_plain_chunk_parses_to_the_raw_dtypes() -> None:
    line = " 1 0 1 1113433184300 7.5 2 3 4 5 6 2 7 8 1 0 5 0.00 9999.99 \n"
    rows = whitespace.parse_plain((line * 3).encode(), 10, 3)
    assert rows is not None and rows.height == 3
    assert rows[files.ROW].to_list() == [10, 11, 12]
    assert rows.select(ns.TXT_COLUMNS).schema == pl.Schema(ns.RAW_SCHEMA)
    assert rows[ns.LOCAL_X].to_list() == [7.5] * 3
    assert np.array_equal(rows[ns.GLOBAL_TIME].to_numpy(), [1113433184300] * 3)
