"""A finished build, opened: its manifest, config, memory-mapped arrays and samples.

Opening reads the manifest and checks it (its checksum, its config hash), that it lists every
file the layout reads (a manifest re-sealed without a file's record would leave it unchecked),
and every file it lists: its size, an array's dtype and shape, and its sampled digest (the whole
of a file up to 8 MiB, 1 MiB spread over a larger one: 86 MB of the six-recording build's
1.64 GB). The arrays are memory-mapped, nothing else is loaded until used, and every read checks
again that the manifest lists its file. Every path comes from `layout`, never
from the manifest. See `integrity`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import polars as pl

from ngsim_graphs import integrity, layout, storage
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.graphs import GraphBatch, NonFiniteStateError, concat_batches, induce_graphs
from ngsim_graphs.grid import ARRAY_NAMES, RecordingArrays, pair_table
from ngsim_graphs.manifest import Manifest, RecordingEntry
from ngsim_graphs.schema import Split
from ngsim_graphs.splits import split_named


@dataclass(frozen=True)
class OpenBuild:
    """A finished build directory, opened for reading."""

    root: Path
    manifest: Manifest
    config: BuildConfig

    def _listed(self, path: Path) -> Path:
        """`path`, a file of the build that the manifest lists (checked on opening); an error
        naming it otherwise: every read goes through here."""
        integrity.listed_record(self.root, path, self.manifest.files)
        return path

    def _open_arrays(self, folder: Path, names: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Memory-mapped arrays of `folder`, each checked against its record in the manifest."""
        for name in names:
            self._listed(folder / f"{name}.npy")
        arrays = storage.open_arrays(folder, names)
        records = self.manifest.files
        for name, array in arrays.items():
            path = folder / f"{name}.npy"
            integrity.check_array(path, array, records.get(path.relative_to(self.root).as_posix()))
        return arrays

    @cached_property
    def entries(self) -> tuple[RecordingEntry, ...]:
        """The manifest's recordings, by recording index."""
        return tuple(sorted(self.manifest.recordings, key=lambda r: r.index))

    @cached_property
    def recordings(self) -> tuple[RecordingArrays, ...]:
        """Frame arrays of each recording, by recording index (memory-mapped)."""
        opened = []
        for entry in self.entries:
            folder = layout.recording_arrays_dir(self.root, entry.location, entry.period)
            arrays = self._open_arrays(folder, ARRAY_NAMES)
            opened.append(RecordingArrays(**arrays, first_track_id=entry.first_track_id))
        return tuple(opened)

    def samples(self, split: Split | str) -> pl.DataFrame:
        """The samples table of a split (SAMPLE_SCHEMA and graph counts)."""
        return read_table(self._listed(layout.samples_path(self.root, split_named(split).value)))

    def tracks(self) -> pl.LazyFrame:
        """The tracks tables of every recording, scanned lazily (TRACKS_SCHEMA)."""
        paths = [layout.tracks_path(self.root, r.location, r.period) for r in self.entries]
        return pl.scan_parquet([self._listed(path) for path in paths])

    def proximity(self, recording: int) -> pl.DataFrame:
        """The proximity pairs of a recording (its index, `entries`) as a table: every pair of
        vehicles at most d_min apart at a grid step (PROXIMITY_SCHEMA: step, track_a, track_b,
        distance_m; sorted so), from its pair arrays (distances their float32 values)."""
        if not 0 <= recording < len(self.entries):
            raise ValueError(
                f"recording {recording}: the build has recordings 0..{len(self.entries) - 1}"
            )
        return pair_table(self.recordings[recording])

    @cached_property
    def _sample_arrays(self) -> dict[Split, dict[str, np.ndarray]]:
        return {}  # filled by sample_arrays, one split at a time

    def sample_arrays(self, split: Split | str) -> dict[str, np.ndarray]:
        """recording_index, ego_track_id and start_step of every sample of a split (memory-mapped,
        read-only; opened once per split and shared between callers)."""
        split = split_named(split)
        if split not in self._sample_arrays:
            folder = layout.sample_arrays_dir(self.root, split.value)
            arrays = self._open_arrays(folder, layout.SAMPLE_ARRAYS)
            size = self.manifest.splits[split.value]
            if any(len(a) != size for a in arrays.values()):
                raise NgsimInputError(
                    folder,
                    f"the arrays do not hold the {size:,} samples of the manifest's {split.value} split",
                )
            self._sample_arrays[split] = arrays
        return self._sample_arrays[split]

    def graphs(self, split: Split | str, sample_ids: np.ndarray, first_step: int = 0) -> GraphBatch:
        """The graphs of the given samples of a split, in the given order.

        `first_step`: keep history steps first_step..K_H-1 only (see `induce_graphs`).
        """
        arrays = self.sample_arrays(split)
        ids = np.asarray(sample_ids, dtype=np.int64)
        recording = np.asarray(arrays["recording_index"][ids])
        # Induce per run of equal recordings, so that any order of samples is kept.
        runs = np.flatnonzero(np.diff(recording)) + 1
        batches = [
            self._induce(int(recording[part[0]]), arrays, ids[part], first_step)
            for part in np.split(np.arange(len(ids)), runs)
            if len(part)
        ]
        if not batches:
            raise ValueError("no samples asked for")
        return concat_batches(batches)

    def _induce(
        self, recording: int, arrays: dict[str, np.ndarray], ids: np.ndarray, first_step: int
    ) -> GraphBatch:
        """The graphs of samples `ids` of one recording; an error naming the file for a sample
        that does not fit its recording or for values that are not finite (a damaged build)."""
        if not 0 <= recording < len(self.recordings):
            raise NgsimInputError(
                self.root, f"a sample names recording {recording}, which the build does not have"
            )
        entry = self.entries[recording]
        folder = layout.recording_arrays_dir(self.root, entry.location, entry.period)
        try:
            batch = induce_graphs(
                self.recordings[recording],
                np.asarray(arrays["ego_track_id"][ids]),
                np.asarray(arrays["start_step"][ids]),
                self.config,
                first_step,
            )
        except NonFiniteStateError:
            batch = None
        except (IndexError, ValueError) as err:
            raise NgsimInputError(
                folder, f"the samples do not fit this recording's arrays (damaged?): {err}"
            ) from None
        if batch is None or not (
            np.isfinite(batch.node_features).all() and np.isfinite(batch.target_xy).all()
        ):
            raise NgsimInputError(
                folder / "node_state.npy", "holds values that are not finite (damaged?)"
            )
        return batch


def read_table(path: Path) -> pl.DataFrame:
    """A Parquet table of a build; one line naming the file if it cannot be read."""
    try:
        return pl.read_parquet(path)
    except (pl.exceptions.PolarsError, OSError) as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise NgsimInputError(path, f"unreadable table (damaged?): {first}") from None


def build_files(root: Path, manifest: Manifest) -> list[Path]:
    """Every file of a build that the layout reads or writes for the manifest's recordings and
    splits: each must be listed in the manifest, so that every read of one is checked."""
    paths = []
    for entry in manifest.recordings:
        key = (entry.location, entry.period)
        folder = layout.recording_arrays_dir(root, *key)
        paths.append(layout.tracks_path(root, *key))
        if layout.has_proximity_tables(manifest.format_version):
            paths.append(layout.proximity_path(root, *key))
        paths += [folder / f"{name}.npy" for name in ARRAY_NAMES]
    for split in Split:
        folder = layout.sample_arrays_dir(root, split.value)
        paths.append(layout.samples_path(root, split.value))
        paths += [folder / f"{name}.npy" for name in layout.SAMPLE_ARRAYS]
    return paths


def open_build(root: str | os.PathLike[str]) -> OpenBuild:
    """Open a finished build, its files checked against the manifest (`integrity.check_files`),
    every file the layout reads among them; a clear error for anything else (not a build,
    unfinished, other version, edited, damaged, a file it reads that the manifest leaves out)."""
    root = Path(root)
    manifest = layout.read_manifest(root)  # typed: of a form that `Manifest` reads
    path = layout.manifest_path(root)
    try:
        for entry in manifest.recordings:
            for name in (entry.location, entry.period):
                integrity.inside(root, name, path)  # a name of the build, never a path
        integrity.check_listed(root, build_files(root, manifest), manifest.files)
        integrity.check_files(root, manifest.files, path)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        if isinstance(err, NgsimInputError):
            raise
        raise NgsimInputError(path, f"unreadable build manifest: {err!r}") from None
    return OpenBuild(root=root, manifest=manifest, config=manifest.config)


@dataclass(frozen=True)
class Verification:
    """What `verify_build` read and found."""

    files: int
    bytes: int
    problems: tuple[str, ...]  # one line per damaged, missing, edited or unlisted file or link


def verify_build(
    root: str | os.PathLike[str], progress: Callable[[str, int, int], None] | None = None
) -> Verification:
    """Read every file of a build and compare it with the manifest's checksums (and the manifest
    with its own); name every file the manifest does not list (but its log, layout.BUILD_LOG)
    and every symbolic link. Unlike
    `open_build`, which samples large files, this reads it all."""
    root = Path(root)
    records = layout.read_manifest(root).files
    problems = integrity.verify_files(root, records, layout.manifest_path(root), progress)
    problems += integrity.stray_entries(root, records, own=(layout.MANIFEST_NAME, layout.BUILD_LOG))
    size = sum(record["bytes"] for record in records.values())
    return Verification(files=len(records), bytes=size, problems=tuple(problems))
