"""What both programs share on the terminal: one line for an interrupt, whatever a library made
of it; plain progress lines at a bounded rate where stderr is not a terminal."""

from __future__ import annotations

import signal

import pytest
import typer

from ngsim_cli.console import PlainProgress, exit_on_error, exit_on_interrupt


class _Callback:
    """A library's callback that a Ctrl-C lands in: its KeyboardInterrupt cannot propagate
    (Python reports it as "Exception ignored in")."""

    def __del__(self) -> None:
        signal.raise_signal(signal.SIGINT)


def test_an_interrupt_a_library_made_its_own_error_is_one_line(
    capfd: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(typer.Exit) as stop, exit_on_interrupt("nothing written"):
        _Callback()  # dropped at once: its KeyboardInterrupt is unraisable
        raise TypeError("'<unprintable str object>' is not a Polars data type")  # as Polars does
    assert stop.value.exit_code == 130
    assert capfd.readouterr().err == "interrupted; nothing written\n"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_sigterm_is_one_line_and_143(capfd: pytest.CaptureFixture[str]) -> None:
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(typer.Exit) as stop, exit_on_interrupt("nothing written (out is as it was)"):
        signal.raise_signal(signal.SIGTERM)
    assert stop.value.exit_code == 143
    assert capfd.readouterr().err == "terminated; nothing written (out is as it was)\n"
    assert signal.getsignal(signal.SIGTERM) is before


def test_an_error_with_no_signal_is_left_as_it_is(capfd: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(TypeError, match="a bug"), exit_on_interrupt("nothing written"):
        raise TypeError("a bug")
    assert capfd.readouterr().err == ""


def test_an_ignored_ctrl_c_stays_ignored() -> None:
    """A shell's background job, `nohup`: SIGINT ignored, and left so."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with exit_on_interrupt("nothing written"):
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            signal.raise_signal(signal.SIGINT)
    finally:
        signal.signal(signal.SIGINT, previous)


def test_an_interrupt_a_library_made_an_os_error_is_the_interrupt_not_an_error(
    capfd: pytest.CaptureFixture[str],
) -> None:
    """The commands nest exit_on_error inside exit_on_interrupt: once a signal has come, the
    error is the interrupt's."""
    with pytest.raises(typer.Exit) as stop, exit_on_interrupt("nothing written"), exit_on_error():
        _Callback()
        raise OSError(5, "Input/output error", "raw.txt")
    assert stop.value.exit_code == 130
    assert capfd.readouterr().err == "interrupted; nothing written\n"


def test_an_os_error_with_no_signal_is_one_error_line(capfd: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(typer.Exit) as stop, exit_on_interrupt("nothing written"), exit_on_error():
        raise OSError(5, "Input/output error", "raw.txt")
    assert stop.value.exit_code == 1
    assert capfd.readouterr().err == "error: raw.txt: Input/output error\n"


def test_plain_progress_is_a_line_every_interval_and_at_the_end_of_a_stage_it_reported() -> None:
    lines: list[str] = []
    now = [0]
    progress = PlainProgress(lines.append, 30.0, lambda: now[0])
    now[0] = 1
    progress("reading", 0, 10)  # the stage starts at 1 s: no line before 30 s from the start
    for second in range(32, 92):  # 60 calls, one a second
        now[0] = second
        progress("reading", (second - 21) // 10, 10)  # 1 at 31 s ... 7 at 91 s
    now[0] = 92
    progress("reading", 10, 10)
    now[0] = 93
    progress("writing", 0, 3)  # a new total: a new stage
    progress("writing", 3, 3)  # it ended without a line before: none now
    assert lines == [
        "reading: 1/10 (10%), 0:00:31 elapsed, about 0:04:39 left",  # 30 s from the start
        "reading: 4/10 (40%), 0:01:01 elapsed, about 0:01:32 left",  # 6 steps at 61 s / 4
        "reading: 10/10 (100%), 0:01:31 elapsed",  # the end of a stage that had a line
    ]


def test_plain_progress_repeats_no_line_and_names_a_step_without_a_count() -> None:
    lines: list[str] = []
    progress = PlainProgress(lines.append, 0.0, lambda: 5.0)
    progress("writing raw/a.txt", 0, 0)
    progress("writing raw/a.txt", 0, 0)
    progress("fit, epoch 1/2", 0, 8)  # nothing done yet: no time left to say
    assert lines == ["writing raw/a.txt", "fit, epoch 1/2: 0/8 (0%), 0:00:00 elapsed"]
