"""How a command ends on an error or a signal (ngsim_cli.exits): one line for an interrupt,
whatever a library made of it; one line for an OS error."""

from __future__ import annotations

import signal

import pytest
import typer

from ngsim_cli.exits import exit_on_error, exit_on_interrupt


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
