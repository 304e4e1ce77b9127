"""highD recordings: their keys, their files' names, their frame clock and the location filter.

A recording is one highD recording id; its key is (location, period) =
(`highd-<locationId>`, `<id, two digits>`), e.g. ("highd-2", "01"): file-system safe, and sorted
like highD's own numbering. Its three files lie side by side and share the prefix `NN_`:
`01_tracks.csv`, `01_tracksMeta.csv`, `01_recordingMeta.csv`.

This module imports nothing of the build config, which uses it to validate location names.
"""

from __future__ import annotations

import re
from pathlib import Path

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources import contract
from ngsim_graphs.sources.highd.schema import HighdFile

FRAME_RATE_HZ = 25  # every highD recording
FRAME_PERIOD_S = 1 / FRAME_RATE_HZ  # 0.04 s
FRAME_PERIOD_MS = 40
LOCATION_PREFIX = "highd-"
_LOCATION = re.compile(rf"^{LOCATION_PREFIX}[1-9][0-9]*$")
_FILE_NAME = re.compile(r"^([0-9]+)_(tracks|tracksMeta|recordingMeta)\.csv$", re.IGNORECASE)
_KINDS = {kind.value.lower(): kind for kind in HighdFile}


def location_name(location_id: int) -> str:
    """The location of a recording's key: `highd-2` for locationId 2."""
    return f"{LOCATION_PREFIX}{location_id}"


def period_name(recording_id: int) -> str:
    """The period of a recording's key: `01` for recording id 1."""
    return f"{recording_id:02d}"


def is_highd_location(name: str) -> bool:
    """Whether `name` names a highD location (`highd-N`, N >= 1)."""
    return bool(_LOCATION.match(name))


def chosen_locations(locations: tuple[str, ...]) -> tuple[str, ...] | None:
    """The highD locations a build keeps: those of `locations` that name one; None (every
    location) when none does, so that the default NGSIM names keep every highD recording."""
    named = tuple(name for name in locations if is_highd_location(name))
    return named or None


def parse_file_name(path: Path) -> tuple[str, HighdFile] | None:
    """(recording prefix `NN`, file kind) of a highD file name, or None for another name."""
    found = _FILE_NAME.match(path.name)
    if found is None:
        return None
    return found.group(1), _KINDS[found.group(2).lower()]


def sibling(path: Path, prefix: str, kind: HighdFile) -> Path:
    """The file of recording `prefix` and `kind` in the folder of `path`."""
    return path.with_name(f"{prefix}_{kind.value}.csv")


def frames_per_step(time_step_s: float, path: Path) -> int:
    """highD frames per grid step (5 for 0.2 s); a step that is not whole frames is an error."""
    try:
        return contract.frames_per_step(time_step_s, FRAME_PERIOD_S)
    except ValueError:
        raise NgsimInputError(
            path,
            f"the grid step of {time_step_s:g} s is not a multiple of highD's frame period "
            f"({FRAME_PERIOD_S:g} s, {FRAME_RATE_HZ} Hz): choose a multiple of 0.2 s",
        ) from None
