"""Delimited text read a line at a time: a line longer than any row is found without reading
it whole."""

from __future__ import annotations

from pathlib import Path

import pytest

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources import text
from ngsim_graphs.sources.text import check_line_lengths, long_line_at


@pytest.mark.parametrize(
    ("data", "at"),
    [
        (b"ab\ncdef\ng\n", 3),  # "cdef" is 4 bytes
        (b"ab\ncde\nfgh\nijk", None),  # every line 3 bytes at most, the last without its end
        (b"ab\ncdefg", 3),  # a last line without its end, already too long
        (b"abcd\n", 0),
        (b"abc\r\n", 0),  # CR is a byte of the line
        (b"", None),
    ],
)
def test_the_first_line_longer_than_the_bound(data: bytes, at: int | None) -> None:
    assert long_line_at(data, max_line_bytes=3) == at


def test_a_file_s_long_line_is_named_from_its_first_part(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(text, "_SCAN_BYTES", 64)  # parts of 64 bytes: a line spans many
    path = tmp_path / "a.txt"
    path.write_bytes(b"1 2 3\n" * 40 + b"0" * 10_000 + b"\n1 2 3\n")
    with pytest.raises(NgsimInputError) as raised:
        check_line_lengths(path)
    assert str(raised.value) == (
        f"{path}, line 41: a line longer than 4,096 bytes, which no trajectory row is "
        "(binary data? no line ends?)"
    )
    path.write_bytes(b"1 2 3\n" * 40 + b"0" * 4_096 + b"\n1 2 3")  # at the bound: read
    check_line_lengths(path)
