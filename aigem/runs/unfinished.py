"""A run that a fit left before its first checkpoint: the only non-empty folder a fresh fit
takes. Such a folder carries fit's marker STARTED (a regular file of STARTED_LINE), written before
anything else and removed once the first last.pt is kept, and besides it only a run's files.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from aigem.runs.records import (
    EARLY_FILES,
    FIT_LOG,
    HORIZONS,
    LAST,
    RUN_FILES,
    RUN_INFO,
    STARTED,
    STARTED_LINE,
    member_dir,
    read_horizons,
    read_record,
)
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.partial_files import create_exclusive, partial_of, write_failure


def is_started(folder: Path) -> bool:
    """Whether `folder` holds fit's marker STARTED: a regular file (not a link) of its line."""
    path = folder / STARTED
    try:
        mode = path.lstat().st_mode
        return stat.S_ISREG(mode) and path.read_bytes() == STARTED_LINE
    except OSError:
        return False


def _regular_file(path: Path) -> bool:
    return path.is_file() and not path.is_symlink()


def unfinished_start(run_dir: Path) -> bool:
    """Whether `run_dir` is, beyond doubt, what a fit left before its first checkpoint: fit's
    marker STARTED, and besides it only files of EARLY_FILES (regular files; run.json an aigem
    run's) and partial files of a run's files."""
    if not is_started(run_dir) or os.path.lexists(run_dir / LAST):
        return False
    for entry in run_dir.iterdir():
        if entry.name == STARTED or partial_of(entry.name) in RUN_FILES:
            continue
        if entry.name not in EARLY_FILES or not _regular_file(entry):
            return False
    if (run_dir / RUN_INFO).exists():
        try:
            read_record(run_dir)
        except NgsimInputError:
            return False
    return True


def unfinished_group(run_dir: Path, horizons_s: tuple[float, ...]) -> bool:
    """Whether `run_dir` is, beyond doubt, what a multi-horizon fit of `horizons_s` left before
    any model kept a checkpoint: fit's marker, its horizons.json (if written yet, a regular file
    of these horizons), its log, and member folders each empty or `unfinished_start`."""
    if not is_started(run_dir):
        return False
    members = {member_dir(run_dir, h).name for h in horizons_s}
    for entry in run_dir.iterdir():
        if entry.name == STARTED or partial_of(entry.name) == HORIZONS:
            continue
        if entry.name in (HORIZONS, FIT_LOG):
            if not _regular_file(entry):
                return False
            continue
        if entry.name not in members or entry.is_symlink() or not entry.is_dir():
            return False
        if any(entry.iterdir()) and not unfinished_start(entry):
            return False
    try:
        return read_horizons(run_dir) in (None, horizons_s)
    except NgsimInputError:
        return False


def mark_started(folder: Path) -> None:
    """Write fit's marker into `folder` (new or empty, or unfinished: it may be there already):
    created exclusively, never through a link."""
    path = folder / STARTED
    if is_started(folder):
        return
    try:
        with create_exclusive(path) as marker:
            marker.write(STARTED_LINE)
    except OSError as err:
        if not isinstance(err, FileExistsError):  # ours, half written: a full disk
            path.unlink(missing_ok=True)
        raise write_failure(path, err) from None


def unmark_started(folder: Path) -> None:
    """Remove fit's marker from `folder` (its first checkpoint is kept, or it is discarded)."""
    if is_started(folder):
        (folder / STARTED).unlink(missing_ok=True)


def refuse_other_contents(run_dir: Path, what: str, ours: frozenset[str] | set[str]) -> None:
    """Refuse a directory that is not empty and not `what`, naming what it holds: beside fit's
    marker, the entries that are not among the names `ours` (all of them without the marker)."""
    started = is_started(run_dir)
    entries = sorted(
        p.name
        for p in run_dir.iterdir()
        if not started
        or not (p.name in ours or p.name == STARTED or partial_of(p.name) in RUN_FILES)
    )
    if entries:
        shown = ", ".join(entries[:3]) + (
            f" and {len(entries) - 3} more" if len(entries) > 3 else ""
        )
        written = ", which fit did not write" if started else ""
        raise NgsimOutputError(
            run_dir,
            f"directory is not empty and is not {what}: it holds {shown}{written}; "
            "choose a new or empty --out",
        )
    raise NgsimOutputError(
        run_dir,
        f"is not {what} that fit left unfinished (its files are links, folders or damaged); "
        "choose a new or empty --out",
    )
