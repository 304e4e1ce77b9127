"""Which source reads the given inputs: every dataset the pipeline knows, by name.

Without a forced dataset the inputs' content decides: a file whose header is one of highD's
three is highD's, one that NGSIM's reader recognises is NGSIM's. A highD file whose header is
damaged (`highd.files.sniff_highd` still tells its kind) is refused at once, naming the column,
whatever lies beside it. Inputs holding both are an error that asks for `--dataset`; inputs
holding neither go to NGSIM, whose reader says why they are no use.
"""

from __future__ import annotations

from pathlib import Path

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.contract import Source
from ngsim_graphs.sources.highd.files import check_header, sniff_highd
from ngsim_graphs.sources.highd.tracks import SOURCE as HIGHD
from ngsim_graphs.sources.ngsim.files import CANDIDATE_SUFFIXES, NotNgsimFileError, sniff_format
from ngsim_graphs.sources.ngsim.tracks import SOURCE as NGSIM

SOURCES: dict[str, Source] = {NGSIM.name: NGSIM, HIGHD.name: HIGHD}
DISPLAY_NAMES: dict[str, str] = {NGSIM.name: "NGSIM", HIGHD.name: "highD"}
DATASET_NAMES: tuple[str, ...] = tuple(SOURCES)


def choose_source(
    paths: list[Path], dataset: str | None = None
) -> tuple[Source, list[Path], list[Path]]:
    """(the source, its files to read, files skipped) for `paths`; `dataset` forces the source."""
    if dataset is not None and dataset not in SOURCES:
        raise NgsimInputError(
            paths[0], f"unknown dataset {dataset!r}; choose from {', '.join(DATASET_NAMES)}"
        )
    source = SOURCES[dataset or detect_dataset(paths)]
    files, skipped = source.find_files(paths)
    return source, files, skipped


def _dataset_of(path: Path, named: bool) -> str | None:
    """The dataset whose file `path` is, by content; None for a file of neither found in a
    folder. A named file that is not highD's is NGSIM's: its reader says what is wrong."""
    highd = sniff_highd(path)
    if highd is not None:
        check_header(path, highd)  # a damaged highD header: refused here, naming its column
        return HIGHD.name
    if named:
        return NGSIM.name
    try:
        sniff_format(path)
    except NotNgsimFileError:
        return None
    except NgsimInputError:
        pass  # NGSIM's, but unreadable: its reader will say why
    return NGSIM.name


def detect_dataset(paths: list[Path]) -> str:
    """The name of the dataset the files under `paths` belong to (NGSIM when none is found).

    Raises NgsimInputError when they hold files of more than one dataset.
    """
    first: dict[str, Path] = {}
    for path in paths:
        if path.is_file():
            candidates = [(path, True)]
        elif path.is_dir():
            found = (
                p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in CANDIDATE_SUFFIXES
            )
            candidates = [(p, False) for p in sorted(found)]
        else:
            continue  # missing: the source's find_files says so
        for candidate, named in candidates:
            name = _dataset_of(candidate, named)
            if name is not None:
                first.setdefault(name, candidate)
    if len(first) > 1:
        held = " and ".join(
            f"{DISPLAY_NAMES[name]} files ({first[name]})"
            for name in DATASET_NAMES
            if name in first
        )
        raise NgsimInputError(
            paths[0] if len(paths) == 1 else ", ".join(map(str, paths)),
            f"the inputs hold {held}; choose one with --dataset {' or --dataset '.join(DATASET_NAMES)}",
        )
    return next(iter(first), NGSIM.name)
