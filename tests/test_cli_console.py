"""What both programs share on the terminal: one line for an interrupt, whatever a library made
of it; plain progress lines at a bounded rate where stderr is not a terminal."""

from __future__ import annotations

import signal

import pytest
import typer

from ngsim_cli import console
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


def test_plain_progress_is_a_line_every_interval_and_at_the_end_of_each_stage() -> None:
    lines: list[str] = []
    now = [0]
    progress = PlainProgress(lines.append, 30.0, lambda: now[0])
    now[0] = 1
    progress("reading", 0, 10)  # a stage's start says nothing
    for second in range(32, 92):  # 60 calls, one a second
        now[0] = second
        progress("reading", (second - 21) // 10, 10)  # 1 at 31 s ... 7 at 91 s
    now[0] = 92
    progress("reading", 10, 10)
    progress("reading", 10, 10, "more")  # its end again (another detail): no line
    now[0] = 93
    progress("writing", 0, 3)  # a new stage
    progress("writing", 3, 3)  # its end: a line, though it had none before
    progress("writing b.txt", 0, 0)  # a step without a count: within the interval, none
    assert lines == [
        "reading: 1/10 (10%), 0:00:31 elapsed, about 0:04:39 left",  # 30 s from the start
        "reading: 4/10 (40%), 0:01:01 elapsed, about 0:01:32 left",  # 6 steps at 61 s / 4
        "reading: 10/10 (100%), 0:01:31 elapsed",  # the end of the stage
        "writing: 3/3 (100%), 0:00:00 elapsed",
    ]


def test_plain_progress_repeats_no_count_and_starts_a_stage_where_what_changes() -> None:
    lines: list[str] = []
    now = [5.0]
    progress = PlainProgress(lines.append, 0.0, lambda: now[0])
    progress("writing raw/a.txt", 0, 0)
    progress("writing raw/a.txt", 0, 0)
    progress("epoch 1/2", 0, 8)  # nothing done yet: no time left to say
    now[0] = 7.0
    progress("epoch 1/2", 2, 8, "loss 2.000 m²")  # the detail after the count
    progress("epoch 2/2", 5, 8)  # another stage: its own elapsed time, no rate yet
    progress("epoch 2/2", 8, 8, "loss 1.500 m²")
    progress("epoch 2/2", 8, 8, "loss 1.400 m²")  # the same count: none
    assert lines == [
        "writing raw/a.txt",
        "epoch 1/2: 0/8 (0%), 0:00:00 elapsed",
        "epoch 1/2: 2/8 (25%), 0:00:02 elapsed, about 0:00:06 left; loss 2.000 m²",
        "epoch 2/2: 5/8 (62%), 0:00:00 elapsed",
        "epoch 2/2: 8/8 (100%), 0:00:00 elapsed; loss 1.500 m²",
    ]


def test_a_logs_progress_lines_are_held_while_the_command_is_young(
    monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """Off a terminal each line of the course after the time it was made; progress lines held
    until the command has run the hold (then written in order, and later ones at once), a line
    that is written at once comes, or the command ends well; dropped where it ends on an error
    first, so that the error's line stands alone."""
    monkeypatch.setattr(console.time, "strftime", lambda _format: "T")
    now = [0.0]
    held = console._HeldLines(30.0, lambda: now[0])
    held.write("a")
    now[0] = 29.0
    held.write("b")
    assert capfd.readouterr().err == ""
    now[0] = 30.0
    held.write("c")  # the hold is over: all three, in order
    held.write("d")
    assert capfd.readouterr().err == "T a\nT b\nT c\nT d\n"
    with pytest.raises(ValueError), console._lines_held(30.0) as young:
        young.write("reading: 1/1 (100%)")
        raise ValueError("the input's error")
    assert capfd.readouterr().err == ""  # dropped: the error's line alone
    with console._lines_held(30.0) as young:
        young.write("reading: 1/1 (100%)")
        assert capfd.readouterr().err == ""
        console.progress_line("epoch 1: ...")  # at once, after the lines held before it
        assert capfd.readouterr().err == "T reading: 1/1 (100%)\nT epoch 1: ...\n"
        young.write("writing: 1/1 (100%)")
    assert capfd.readouterr().err == "T writing: 1/1 (100%)\n"  # the block ended well
