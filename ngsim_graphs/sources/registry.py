"""Which source reads the given inputs: every dataset the pipeline knows, by name."""

from __future__ import annotations

from pathlib import Path

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.contract import Source
from ngsim_graphs.sources.ngsim.tracks import SOURCE as NGSIM

SOURCES: dict[str, Source] = {NGSIM.name: NGSIM}
DATASET_NAMES: tuple[str, ...] = tuple(SOURCES)


def choose_source(paths: list[Path], dataset: str | None = None) -> tuple[Source, list[Path], list[Path]]:
    """(the source, its files to read, files skipped) for `paths`; `dataset` forces the source."""
    if dataset is not None and dataset not in SOURCES:
        raise NgsimInputError(paths[0], f"unknown dataset {dataset!r}; choose from {', '.join(DATASET_NAMES)}")
    source = SOURCES[dataset or NGSIM.name]
    files, skipped = source.find_files(paths)
    return source, files, skipped
