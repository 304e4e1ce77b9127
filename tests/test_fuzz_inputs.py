"""The input fuzz of bench/fuzz_inputs.py: damaged inputs give a plausible build or a one-line
error, never a traceback, a hang or rows lost without a word (issue 9)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import fuzz_inputs as fz
import fuzz_mutations as fm

# Cases of the default plan (seed 0), so that the full run repeats them: the three unmutated
# inputs and every family of mutation (truncation, byte flips, field values, header or column
# swaps, extra columns, non-UTF-8 bytes, deleted and duplicated lines, CR line ends, other file
# types), each format more than once.
FAST_CASE_INDICES = (0, 1, 2, 5, 10, 21, 25, 42, 49, 59, 61, 64, 68, 71, 72)


def test_fast_cases_succeed_plausibly_or_fail_cleanly(tmp_path: Path) -> None:
    plan = fm.plan_cases(seed=0)
    cases = [plan[i] for i in FAST_CASE_INDICES]
    families = {fm.MUTATIONS[c.kind][0] for c in cases}
    assert families == {family for family, _ in fm.MUTATIONS.values()}
    outcomes = fz.run_cases(cases, tmp_path, jobs=2)
    assert [o.status for o in outcomes[:3]] == [fz.SUCCESS] * 3  # the unmutated inputs build
    assert not [o for o in outcomes if o.status == fz.OTHER], fz.describe_others(outcomes)


@pytest.mark.slow
def test_full_default_fuzz(tmp_path: Path) -> None:
    outcomes = fz.run_cases(fm.plan_cases(seed=0), tmp_path, jobs=2)
    assert not [o for o in outcomes if o.status == fz.OTHER], fz.describe_others(outcomes)


def test_mutations_are_seeded() -> None:
    case = fm.Case(index=3, seed=0, fmt="portal", kind="flip_bytes")
    assert fm.make_input(case) == fm.make_input(case)
    assert fm.make_input(case) != fm.make_input(fm.Case(3, 1, "portal", "flip_bytes"))


def test_default_plan_covers_every_kind_and_format() -> None:
    plan = fm.plan_cases(seed=0)
    assert len(plan) == fm.DEFAULT_CASES
    assert {(c.kind, c.fmt) for c in plan} == {(k, f) for k in fm.MUTATIONS for f in fm.FORMATS}


def test_data_lines_are_counted_as_the_reader_splits_them() -> None:
    for fmt in fm.FORMATS:
        assert fm.count_data_lines(fm.base_input(fmt), fmt) == (1000, 1000)
    # CSV: the header is not data; CRLF and a blank line at the end are no rows; a line of
    # spaces is a (valueless) row to a CSV reader, so it may or may not be counted.
    assert fm.count_data_lines(b"\xef\xbb\xbfa,b\r\n1,2\r\n  \r\n3,4\r\n\r\n", "portal") == (2, 3)
    assert fm.count_data_lines(b"  1 2 \n\n 3 4", "txt") == (2, 2)


def test_portal_fields_keep_their_quotes() -> None:
    body = b'1,"1,118,846,993,000",,us-101'
    spans = fm.field_spans(body, "portal")
    assert [body[a:b] for a, b in spans] == [b"1", b'"1,118,846,993,000"', b"", b"us-101"]
    assert fm.replace_spans(body + b"\r\n", spans, {1: b"nan"}) == b"1,nan,,us-101\r\n"


def _classify(tmp_path: Path, code: int | None, stdout: str, stderr: str) -> tuple[str, str]:
    input_path, out = tmp_path / "a.txt", tmp_path / "out"
    input_path.write_bytes(b"")
    return fz.classify(fz.RunResult(code, stdout, stderr), input_path, out, b"", "txt")


def test_classification_of_failures(tmp_path: Path) -> None:
    path = tmp_path / "a.txt"
    assert _classify(tmp_path, 1, "", f"error: {path}, line 3: bad\n")[0] == fz.CLEAN_ERROR
    assert (
        _classify(tmp_path, 1, "", "error: no rows in any input\n")[0] == fz.OTHER
    )  # names no file
    assert _classify(tmp_path, 1, "", f"error: {path}: one\nerror: two\n")[0] == fz.OTHER
    assert _classify(tmp_path, 1, "table\n", f"error: {path}: x\n")[0] == fz.OTHER
    assert _classify(tmp_path, 3, "", f"error: {path}: x\n")[0] == fz.OTHER
    assert _classify(tmp_path, -11, "", "")[0] == fz.OTHER  # a crash
    assert _classify(tmp_path, None, "", "")[0] == fz.OTHER  # a hang
    traceback = 'Traceback (most recent call last):\n  File "x.py", line 1, in f\nKeyError: 3\n'
    status, detail = _classify(tmp_path, 1, "", traceback)
    assert status == fz.OTHER and "x.py:1 in f" in detail and "KeyError: 3" in detail
    (tmp_path / ".out.partial-123").mkdir()
    status, detail = _classify(tmp_path, 1, "", f"error: {path}: x\n")
    assert status == fz.OTHER and ".out.partial-123" in detail


def test_progress_lines_of_a_build_off_a_terminal_are_no_problem() -> None:
    line = "2026-11-29 07:55:47 reading input files: 1,204/2,000 (60%), 0:00:31 elapsed"
    assert fz.PROGRESS_LINE.match(line)
    assert not fz.PROGRESS_LINE.match("2026-11-29 07:55:47 error: a.txt, line 3: bad")
    assert not fz.PROGRESS_LINE.match("Traceback (most recent call last):")
