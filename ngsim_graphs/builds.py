"""A finished build, opened: its manifest, config, memory-mapped arrays and samples.

Opening costs the same for a tiny build and for the six-recording one: the manifest is read,
the arrays are memory-mapped, nothing else is loaded until used.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from ngsim_graphs import layout
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.frames import ARRAY_NAMES, RecordingArrays
from ngsim_graphs.graphs import GraphBatch, concat_batches, induce_graphs
from ngsim_graphs.schema import Split


@dataclass(frozen=True)
class OpenBuild:
    """A finished build directory, opened for reading."""

    root: Path
    manifest: dict[str, Any]
    config: BuildConfig

    @cached_property
    def recordings(self) -> tuple[RecordingArrays, ...]:
        """Frame arrays of each recording, by recording index (memory-mapped)."""
        opened = []
        for entry in sorted(self.manifest["recordings"], key=lambda r: r["index"]):
            arrays = layout.open_arrays(self.root / entry["arrays_dir"], ARRAY_NAMES)
            opened.append(RecordingArrays(**arrays, first_track_id=entry["first_track_id"]))
        return tuple(opened)

    def samples(self, split: Split | str) -> pl.DataFrame:
        """The samples table of a split (SAMPLE_SCHEMA and graph counts)."""
        return pl.read_parquet(layout.samples_path(self.root, Split(split).value))

    @cached_property
    def _sample_arrays(self) -> dict[Split, dict[str, np.ndarray]]:
        return {}  # filled by sample_arrays, one split at a time

    def sample_arrays(self, split: Split | str) -> dict[str, np.ndarray]:
        """recording_index, ego_track_id and start_step of every sample of a split (memory-mapped,
        read-only; opened once per split and shared between callers)."""
        split = Split(split)
        if split not in self._sample_arrays:
            folder = layout.sample_arrays_dir(self.root, split.value)
            self._sample_arrays[split] = layout.open_arrays(folder, layout.SAMPLE_ARRAYS)
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
            induce_graphs(
                self.recordings[int(recording[part[0]])],
                np.asarray(arrays["ego_track_id"][ids[part]]),
                np.asarray(arrays["start_step"][ids[part]]),
                self.config,
                first_step,
            )
            for part in np.split(np.arange(len(ids)), runs)
            if len(part)
        ]
        if not batches:
            raise ValueError("no samples asked for")
        return concat_batches(batches)


def open_build(root: Path) -> OpenBuild:
    """Open a finished build; a clear error for anything else (unfinished, other version)."""
    manifest = layout.read_manifest(root)
    try:
        config = BuildConfig.from_dict(manifest["config"])
    except (KeyError, TypeError, ValueError) as err:
        raise NgsimInputError(layout.manifest_path(root), f"unreadable build config: {err}") from None
    return OpenBuild(root=root, manifest=manifest, config=config)
