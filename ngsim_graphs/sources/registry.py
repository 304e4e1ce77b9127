"""Which source reads the given inputs: every dataset the pipeline knows, by name.

A new source is its folder and one line in SOURCE_MODULES. Without a forced dataset the inputs' content
decides (each source's `claims`): a file a source claims is that source's, the fallback's
(NGSIM's) last. A file whose source refuses it while claiming it (a highD file whose header is
damaged) is refused at once, naming the column, whatever lies beside it. Inputs holding the
files of more than one are an error that asks for `--dataset`; inputs holding none go to the
fallback, whose reader says why they are no use. A build's locations are checked here too:
each must be a location of some source.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.cleaning import descriptions
from ngsim_graphs.sources.contract import Source
from ngsim_graphs.sources.inputs import files_in

# Every source, one line each: the module of its folder that defines its `SOURCE`. Their order is
# --dataset's and detection's (the fallback asked last).
SOURCE_MODULES: tuple[str, ...] = (
    "ngsim_graphs.sources.ngsim.tracks",
    "ngsim_graphs.sources.highd.tracks",
)
FALLBACK = "ngsim"  # the source of inputs no source claims: its reader says why


def load_source(module: str) -> Source:
    """The `SOURCE` that `module` (a source folder's module, by its import name) defines."""
    source = getattr(importlib.import_module(module), "SOURCE", None)
    if not isinstance(source, Source):
        raise TypeError(f"{module} defines no SOURCE = Source(...)")
    return source


SOURCES: dict[str, Source] = {source.name: source for source in map(load_source, SOURCE_MODULES)}


def dataset_names() -> tuple[str, ...]:
    """The names of the registered sources, in registry order (`--dataset`'s choices)."""
    return tuple(SOURCES)


def label(dataset: str) -> str:
    """The name a person reads of `dataset` ("NGSIM", "highD")."""
    return SOURCES[dataset].label or dataset


def in_words(names: list[str], conjunction: str = "or") -> str:
    """Names as a sentence lists them: "a", "a or b", "a, b or c"."""
    return f" {conjunction} ".join(filter(None, [", ".join(names[:-1]), names[-1]]))


def labels_in_words() -> str:
    """The registered datasets as a person reads them ("NGSIM or highD"): help texts name them
    from here, so that a new source needs no edit of the CLI."""
    return in_words([label(name) for name in SOURCES])


def locations_in_words() -> str:
    """Each source's location names after its label ("NGSIM: us-101, ...; highD: highd-N ...")."""
    return "; ".join(
        f"{label(name)}: {source.locations_help}"
        for name, source in SOURCES.items()
        if source.locations_help
    )


def drop_descriptions(dataset: str) -> dict[str, str]:
    """What the rows dropped for each reason of `dataset`'s builds were, by reason value: the
    shared reasons and its source's own (none for a dataset not registered here)."""
    source = SOURCES.get(dataset)
    return descriptions(source.drop_reasons if source else None)


def check_locations(locations: tuple[str, ...]) -> None:
    """Raise ValueError unless every one of `locations` (at least one) is a location of some
    source (a source's filter is the names of its own locations; none named: all, for highD)."""
    unknown = sorted(
        name
        for name in set(locations)
        if not any(source.is_location(name) for source in SOURCES.values())
    )
    if unknown or not locations:
        known = " or ".join(
            source.locations_help for source in SOURCES.values() if source.locations_help
        )
        raise ValueError(f"unknown location(s) {unknown}; choose from {known}")


def choose_source(
    paths: list[Path], dataset: str | None = None
) -> tuple[Source, list[Path], list[Path]]:
    """(the source, its files to read, files skipped) for `paths`; `dataset` forces the source."""
    if dataset is not None and dataset not in SOURCES:
        raise NgsimInputError(
            paths[0], f"unknown dataset {dataset!r}; choose from {', '.join(SOURCES)}"
        )
    source = SOURCES[dataset or detect_dataset(paths)]
    files, skipped = source.find_files(paths)
    return source, files, skipped


def _claimants() -> list[Source]:
    """The sources in the order they are asked whether a file is theirs: the fallback last."""
    return sorted(SOURCES.values(), key=lambda source: source.name == FALLBACK)


def _dataset_of(path: Path, named: bool) -> str | None:
    """The dataset whose file `path` is, by content; None for a file of none found in a folder.
    A named file that no other source claims is the fallback's: its reader says what is wrong."""
    for source in _claimants():
        if (named and source.name == FALLBACK) or source.claims(path):
            return source.name
    return None


def detect_dataset(paths: list[Path]) -> str:
    """The name of the dataset the files under `paths` belong to (the fallback when none is
    found).

    Raises NgsimInputError when they hold files of more than one dataset.
    """
    first: dict[str, Path] = {}
    for path in paths:
        if path.is_file():
            candidates = [(path, True)]
        elif path.is_dir():
            suffixes = tuple({s for source in SOURCES.values() for s in source.suffixes})
            candidates = [(p, False) for p in files_in(path, suffixes) or []]
        else:
            continue  # missing: the source's find_files says so
        for candidate, named in candidates:
            name = _dataset_of(candidate, named)
            if name is not None:
                first.setdefault(name, candidate)
    if len(first) > 1:
        held = " and ".join(
            f"{label(name)} files ({first[name]})" for name in SOURCES if name in first
        )
        raise NgsimInputError(
            paths[0] if len(paths) == 1 else ", ".join(map(str, paths)),
            f"the inputs hold {held}; choose one with --dataset {' or --dataset '.join(SOURCES)}",
        )
    return next(iter(first), FALLBACK)


def is_source_file(path: Path) -> bool:
    """Whether `path` is a file that some source reads, told from its suffix and content (a
    damaged file that its source still claims is one)."""
    for source in _claimants():
        if path.suffix.lower() not in source.suffixes:
            continue
        try:
            if source.claims(path):
                return True
        except NgsimInputError:
            return True
        except OSError:
            return False
    return False
