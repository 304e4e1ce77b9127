"""The output lock: one writer at a time, created exclusively and never followed, and a killed
run's leftovers (and nothing else beside the output) cleaned up or restored."""

from __future__ import annotations

import fcntl
import os
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from ngsim_graphs import lock
from ngsim_graphs.errors import NgsimOutputError

TOKEN = "0123456789abcdef" * 2  # a killed run's


def siblings(out: Path) -> list[str]:
    """Hidden entries beside `out`: partial and retired directories, the lock file."""
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


def folder(path: Path, content: str) -> Path:
    """A directory holding one file, `keep.txt`, with `content`."""
    path.mkdir(parents=True)
    (path / "keep.txt").write_text(content)
    return path


def killed_run(out: Path) -> None:
    """The lock file a run of `out` holding TOKEN left when it was killed (no flock on it)."""
    lock.lock_path(out).write_text(f"ngsim-graphs lock {TOKEN} 4242\n")


@pytest.fixture
def held(tmp_path: Path) -> Iterator[Path]:
    """`tmp_path/out`, locked by this test as another build would hold it, with PID 4242."""
    out = tmp_path / "out"
    fd = os.open(lock.lock_path(out), os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.write(fd, f"ngsim-graphs lock {TOKEN} 4242\n".encode())
    yield out
    os.close(fd)


# --- one writer at a time --------------------------------------------------------------------


def test_second_writer_is_refused_naming_the_holder(held: Path) -> None:
    with pytest.raises(NgsimOutputError) as caught, lock.output_lock(held):
        pass
    assert str(caught.value) == (
        f"{held}: another process is writing it (process 4242), holding "
        f"{lock.lock_path(held)}; wait for it to finish or choose another --out"
    )


def test_lock_holds_a_line_of_ours_and_is_removed_on_release(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with lock.output_lock(out) as token:
        assert lock.lock_path(out).read_text() == f"ngsim-graphs lock {token} {os.getpid()}\n"
        assert len(token) == 32 and int(token, 16) >= 0
    assert siblings(out) == []


def test_each_run_has_a_token_of_its_own(tmp_path: Path) -> None:
    tokens = set()
    for _ in range(3):
        with lock.output_lock(tmp_path / "out") as token:
            tokens.add(token)
    assert len(tokens) == 3


def test_lock_unlinked_by_its_holder_before_ours_is_taken_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A holder releasing between our open() and our flock() unlinks the file we opened: a lock
    on it would hold nothing, since the next writer creates a new file."""
    out = tmp_path / "out"
    path = lock.lock_path(out)
    killed_run(out)
    real_flock, calls = fcntl.flock, []

    def flock_after_a_release(fd: int, operation: int) -> None:
        calls.append(os.fstat(fd).st_ino)
        if len(calls) == 1:
            path.unlink()  # the holder's release
        real_flock(fd, operation)

    monkeypatch.setattr(lock.fcntl, "flock", flock_after_a_release)
    with lock.output_lock(out) as token:
        assert len(calls) == 2 and calls[1] == path.stat().st_ino
        assert path.read_text() == f"ngsim-graphs lock {token} {os.getpid()}\n"


# --- what is not ours is never touched -------------------------------------------------------


def test_lock_path_that_is_a_link_is_not_followed(tmp_path: Path) -> None:
    out, victim = tmp_path / "out", tmp_path / "victim.txt"
    victim.write_text("precious\n")
    lock.lock_path(out).symlink_to(victim)
    with pytest.raises(NgsimOutputError) as caught, lock.output_lock(out):
        pass
    assert str(caught.value) == (
        f"{lock.lock_path(out)}: is a symbolic link, not a lock of ngsim-graphs: left as it is, "
        f"and {out} not written (remove it if no program is writing {out}, or choose another "
        "--out)"
    )
    assert victim.read_text() == "precious\n" and lock.lock_path(out).is_symlink()


def test_dangling_link_is_not_created_through(tmp_path: Path) -> None:
    out, target = tmp_path / "out", tmp_path / "made-through-the-link"
    lock.lock_path(out).symlink_to(target)
    with pytest.raises(NgsimOutputError, match="is a symbolic link, not a lock"):
        lock.take_lock(out)
    assert not target.exists()


@pytest.mark.parametrize(
    ("make", "what"),
    [
        (lambda path: path.mkdir(), "is not a regular file"),
        (lambda path: os.mkfifo(path), "is not a regular file"),
        (lambda path: path.write_text("4242\n"), "holds something else"),  # an older version's
        (lambda path: path.write_text("my notes\n"), "holds something else"),
    ],
)
def test_lock_path_that_is_not_ours_is_refused_and_left(tmp_path: Path, make, what: str) -> None:  # noqa: ANN001
    out = tmp_path / "out"
    path = lock.lock_path(out)
    make(path)
    before = path.read_text() if path.is_file() else None
    with pytest.raises(NgsimOutputError, match=f"^{path}: {what}, not a lock of ngsim-graphs"):
        lock.take_lock(out)
    assert path.exists() and (before is None or path.read_text() == before)


def test_empty_lock_file_is_waited_for_then_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Empty: its creator has not written its line yet, or was killed in that moment."""
    monkeypatch.setattr(lock, "_EMPTY_LOCK_WAIT_S", 0.0)
    out = tmp_path / "out"
    lock.lock_path(out).write_text("")
    with pytest.raises(NgsimOutputError, match="is an empty file, not a lock of ngsim-graphs"):
        lock.take_lock(out)


def test_siblings_of_our_names_without_our_token_are_never_touched(tmp_path: Path) -> None:
    out = tmp_path / "out"
    mine = [
        folder(tmp_path / ".out.old-backup", "a"),
        folder(tmp_path / ".out.partial-notes", "b"),
        folder(tmp_path / ".out.partial-123", "c"),  # an older version's leftover
        folder(tmp_path / f".out.partial-{'f' * 32}", "d"),  # a token no lock names
    ]
    killed_run(out)  # names TOKEN only
    with lock.output_lock(out):
        pass
    with lock.output_lock(out):  # and without a killed run's lock
        pass
    assert [(p / "keep.txt").read_text() for p in mine] == ["a", "b", "c", "d"]


# --- a killed run's leftovers ----------------------------------------------------------------


def test_killed_run_while_writing_leaves_its_partial_directory_to_the_next(tmp_path: Path) -> None:
    out = folder(tmp_path / "out", "previous")
    partial = folder(lock.partial_path(out, TOKEN), "half")
    killed_run(out)
    with lock.output_lock(out) as token:
        assert not partial.exists() and token != TOKEN
    assert (out / "keep.txt").read_text() == "previous"
    assert siblings(out) == []


def test_killed_run_between_its_renames_gets_the_previous_out_back(tmp_path: Path) -> None:
    out = tmp_path / "out"
    folder(lock.retired_path(out, TOKEN), "previous")
    folder(lock.partial_path(out, TOKEN), "new, complete")
    killed_run(out)
    with lock.output_lock(out):
        assert (out / "keep.txt").read_text() == "previous"
    assert siblings(out) == []


def test_killed_run_after_its_swap_leaves_its_new_out(tmp_path: Path) -> None:
    out = folder(tmp_path / "out", "new")
    folder(lock.retired_path(out, TOKEN), "previous")
    killed_run(out)
    with lock.output_lock(out):
        pass
    assert (out / "keep.txt").read_text() == "new"
    assert siblings(out) == []


def test_previous_out_set_aside_and_a_new_out_made_since_is_refused(tmp_path: Path) -> None:
    out = folder(tmp_path / "out", "made by someone since")
    retired = folder(lock.retired_path(out, TOKEN), "previous")
    folder(lock.partial_path(out, TOKEN), "new, complete")
    killed_run(out)
    with pytest.raises(NgsimOutputError) as caught:
        lock.take_lock(out)
    assert str(caught.value) == (
        f"{retired}: holds the previous out, set aside by a build that was killed, and {out} "
        "has been made since: move one of them away"
    )
    assert (retired / "keep.txt").read_text() == "previous"
    assert lock.lock_path(out).read_text() == f"ngsim-graphs lock {TOKEN} 4242\n"  # kept


def test_leftovers_that_remain_keep_the_lock_file_naming_them(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with lock.output_lock(out) as token:
        folder(lock.partial_path(out, token), "not cleaned up (say, a permission)")
    assert lock.lock_path(out).read_text().startswith(f"ngsim-graphs lock {token} ")
    with lock.output_lock(out):  # the next run cleans them up
        pass
    assert siblings(out) == []


def test_a_ctrl_c_while_the_lock_is_taken_leaves_no_lock_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out"
    taken = lock._take_lock

    def interrupted(path: Path, out: Path) -> tuple[int, str | None]:
        held = taken(path, out)  # the file created and flock-ed, its line not written yet
        signal.raise_signal(signal.SIGINT)  # as Ctrl-C would, right then
        return held

    monkeypatch.setattr(lock, "_take_lock", interrupted)
    with pytest.raises(KeyboardInterrupt):
        lock.take_lock(out)
    assert list(tmp_path.iterdir()) == []  # neither an empty lock file nor one with a line
    monkeypatch.setattr(lock, "_take_lock", taken)
    with lock.output_lock(out):  # and the next run takes it at once
        assert lock.lock_path(out).is_file()
    assert list(tmp_path.iterdir()) == []
