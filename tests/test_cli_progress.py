"""Progress on stderr (ngsim_cli.progress): plain lines at a bounded rate where stderr is not a
terminal, held while the command is young."""

from __future__ import annotations

import pytest

from ngsim_cli import progress as module
from ngsim_cli.progress import PlainProgress


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
    monkeypatch.setattr(module.time, "strftime", lambda _format: "T")
    now = [0.0]
    held = module._HeldLines(30.0, lambda: now[0])
    held.write("a")
    now[0] = 29.0
    held.write("b")
    assert capfd.readouterr().err == ""
    now[0] = 30.0
    held.write("c")  # the hold is over: all three, in order
    held.write("d")
    assert capfd.readouterr().err == "T a\nT b\nT c\nT d\n"
    with pytest.raises(ValueError), module._lines_held(30.0) as young:
        young.write("reading: 1/1 (100%)")
        raise ValueError("the input's error")
    assert capfd.readouterr().err == ""  # dropped: the error's line alone
    with module._lines_held(30.0) as young:
        young.write("reading: 1/1 (100%)")
        assert capfd.readouterr().err == ""
        module.progress_line("epoch 1: ...")  # at once, after the lines held before it
        assert capfd.readouterr().err == "T reading: 1/1 (100%)\nT epoch 1: ...\n"
        young.write("writing: 1/1 (100%)")
    assert capfd.readouterr().err == "T writing: 1/1 (100%)\n"  # the block ended well
