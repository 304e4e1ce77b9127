"""The folder `ngsim-graphs synth` fills: which files a SynthConfig writes there and under which
names (synthetic_paths, period_note), whether synth may replace what the folder holds
(check_synth_target), and the marker that says the data are simulated and lists synth's files.

The folder lands whole (`landing.output_directory`, in synth.formats): its files are written into
a hidden partial folder beside it, each created exclusively and never through a link, and the
finished folder is swapped in, so that an interrupted or killed run leaves nothing that looks
complete (a killed run's partial folder is removed by the next run into the same folder). A
folder synth fills carries `SYNTHETIC.md` (synth.marker reads it back), which says the data are
simulated and lists synth's files with their sha256: synth replaces a folder only when it is new
or empty or holds exactly the files its marker lists, as synth wrote them.
"""

from __future__ import annotations

import os
import re
from dataclasses import replace
from pathlib import Path

from ngsim_graphs import schema
from ngsim_graphs.config import SynthConfig
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.landing import entries_beyond, some_names
from ngsim_graphs.sources.ngsim.recordings import OFFICIAL_RECORDINGS
from ngsim_graphs.synth.highd import highd_paths
from ngsim_graphs.synth.marker import MARKER_NAME

PORTAL_FILE_NAME = "Next_Generation_Simulation__NGSIM__Vehicle_Trajectories_and_Supporting_Data.csv"
# Each official recording's period, which names its files whatever --minutes is (below).
OFFICIAL_PERIOD_MINUTES = 15.0
_DIGEST_LINE = re.compile(r"    ([0-9a-f]{64})  (\S+)")  # a marker's sha256 of one file


def synthetic_paths(out_dir: Path, config: SynthConfig) -> list[Path]:
    """The files that `write_synthetic` writes for `config`, in order."""
    if config.raw_format is schema.RawFormat.PORTAL:
        return [out_dir / PORTAL_FILE_NAME]
    if config.raw_format is schema.RawFormat.HIGHD:
        return highd_paths(out_dir, config.recordings)
    return [
        out_dir / recording.location / f"trajectories-{recording.period}.{config.raw_format.value}"
        for recording in OFFICIAL_RECORDINGS[: config.recordings]
    ]


def period_note(config: SynthConfig) -> str | None:
    """What to tell a user whose recordings are not the official periods' 15 minutes (None where
    they are, or for highD's files): each one starts at its period's official start and keeps
    that period's name. A build tells an NGSIM recording by its frame 0's time, which names the
    period whose start is nearest (`sources.ngsim.recordings`), so a file named by its own
    length would be reported by the build under another name than its own."""
    if config.minutes == OFFICIAL_PERIOD_MINUTES or config.raw_format is schema.RawFormat.HIGHD:
        return None
    per_period = config.raw_format is not schema.RawFormat.PORTAL
    named = "its file's name and a build's report" if per_period else "a build's report"
    return (
        f"each recording runs {config.minutes:g} minutes from the start of its official period "
        f"and is named after that 15-minute period (e.g. 0400-0415) in {named}: a build tells "
        "a recording by its start time"
    )


def check_synth_target(out_dir: Path) -> None:
    """Refuse a folder that synth may not replace: one that is neither new nor empty nor exactly
    an earlier run's files as synth wrote them (`earlier_synth_files`)."""
    if out_dir.exists() and not out_dir.is_dir():
        raise NgsimOutputError(out_dir, "exists and is not a directory")
    if not out_dir.is_dir() or not any(out_dir.iterdir()):
        return
    marker = out_dir / MARKER_NAME
    listed = earlier_synth_files(out_dir)
    if listed is None and not os.path.lexists(marker):
        entries = sorted(p.name for p in out_dir.iterdir())
        raise NgsimOutputError(
            out_dir,
            f"folder is not empty and not synth's (no {MARKER_NAME}): it holds "
            f"{some_names(entries)}; "
            "synth writes only into a new or empty folder or one it wrote before",
        )
    if listed is None:
        raise NgsimOutputError(
            marker,
            "is not a marker that synth wrote (or was edited since: it lists no file with its "
            "sha256): the folder is not replaced; move it away or choose another folder",
        )
    beyond = entries_beyond(out_dir, {MARKER_NAME, *listed})
    changed = [
        name
        for name, digest in listed.items()
        if os.path.lexists(out_dir / name) and _digest(out_dir / name) != digest
    ]
    if beyond or changed:
        raise NgsimOutputError(
            out_dir / (beyond + changed)[0],
            f"not written by synth (not listed in {marker}, or changed since); move it away "
            "first: synth replaces only a folder of its own files",
        )


def _digest(path: Path) -> str | None:
    return file_sha256(path) if path.is_file() and not path.is_symlink() else None


def earlier_synth_files(out_dir: Path) -> dict[str, str] | None:
    """The files an earlier run of synth wrote into `out_dir` (relative name -> sha256), as its
    marker lists them; None where `out_dir` holds no marker of synth's (a link, or a file
    listing no file with its sha256)."""
    marker = out_dir / MARKER_NAME
    if marker.is_symlink() or not marker.is_file():
        return None
    try:
        text = marker.read_text(errors="replace")
    except OSError:
        return None
    digests = _listed_digests(text)
    return digests if digests and set(digests) == _listed_files(text) else None


def relative_name(path: Path, out_dir: Path) -> str:
    """`path`'s name within `out_dir`, as the marker lists it: `us-101/trajectories-...txt`."""
    return path.relative_to(out_dir).as_posix()


def marker_text(config: SynthConfig, digests: dict[str, str]) -> str:
    """What the marker tells a person, and the list of files (with their sha256) that makes
    them synth's."""
    quirks = "on" if config.quirks else "off"
    highd = config.raw_format is schema.RawFormat.HIGHD
    return (
        f"# Synthetic data: NOT real {'highD' if highd else 'NGSIM'} trajectories\n\n"
        "The files listed below were written by `ngsim-graphs synth`: simulated traffic in the\n"
        + ("format of the highD files" if highd else "formats of the NGSIM US-101 / I-80 files")
        + ", not measurements. `ngsim-graphs synth` replaces\n"
        "this folder only while it holds these files and nothing else, each with its sha256 below.\n\n"
        f"Settings: format {config.raw_format.value}, {config.recordings} recordings of "
        f"{config.minutes:g} minutes, seed {config.seed}, quirks {quirks}.\n\n"
        + (f"{note[0].upper()}{note[1:]}.\n\n" if (note := period_note(config)) else "")
        + "Files:\n\n"
        + "".join(f"- {name}\n" for name in digests)
        + "\nsha256 (`sha256sum -c` reads these lines):\n\n"
        + "".join(f"    {digest}  {name}\n" for name, digest in digests.items())
    )


def _possible_names() -> set[str]:
    """Every file name that synth can write (relative to its folder)."""
    everything = SynthConfig(recordings=len(OFFICIAL_RECORDINGS))
    return {
        relative_name(path, Path("."))
        for raw_format in schema.RawFormat
        for path in synthetic_paths(Path("."), replace(everything, raw_format=raw_format))
    }


def _listed_files(text: str) -> set[str]:
    """The files a marker lists (its lines `- NAME`) that synth can write: a list edited to name
    anything else makes nothing else synth's."""
    return {line[2:].strip() for line in text.splitlines() if line.startswith("- ")} & (
        _possible_names()
    )


def _listed_digests(text: str) -> dict[str, str]:
    """The sha256 a marker records of each file synth can write (its lines `    HEX  NAME`)."""
    found = (_DIGEST_LINE.fullmatch(line) for line in text.splitlines())
    possible = _possible_names()
    return {m.group(2): m.group(1) for m in found if m and m.group(2) in possible}
