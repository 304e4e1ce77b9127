"""synth's marker, read back: which files `ngsim-graphs synth` wrote, and so which builds are of
simulated data.

Every folder synth fills carries MARKER_NAME (written by `synth.formats`), which says the data are
simulated and lists the files synth wrote there, one `- NAME` line each, NAME relative to the
folder. A build records its inputs' absolute paths (`manifest.inputs`): it is of synthetic data
when any input is listed by a marker in its folder or the folder above (synth's
`<location>/<file>` layouts). Everything that reports on a build (`stats --json`, `show`,
`aigem evaluate --json` and `--plots`, `fit`'s curves) says so with `synthetic_build`.

Only the marker is read (no simulator is imported): a few small files, once per command. Inputs
moved away or a marker removed since the build make it read as not synthetic.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ngsim_graphs.manifest import Manifest

# Written first into every folder synth fills: says the data are synthetic, lists synth's files.
MARKER_NAME = "SYNTHETIC.md"
# What pictures and tables of a synthetic build say, in these words.
SYNTHETIC_LABEL = "SYNTHETIC data (ngsim-graphs synth), not NGSIM measurements"


def written_by_synth(path: Path) -> bool:
    """Whether `ngsim-graphs synth` wrote the file `path` (absolute): the marker of its folder, or
    of the folder above, lists it."""
    for folder in path.parents[:2]:
        marker = folder / MARKER_NAME
        try:
            listed = marker.read_text(errors="replace").splitlines() if marker.is_file() else []
        except OSError:
            listed = []
        if f"- {path.relative_to(folder).as_posix()}" in listed:
            return True
    return False


def synthetic_build(manifest: Manifest) -> bool:
    """Whether the build of `manifest` is of synthetic data: synth wrote any of its inputs."""
    return any(written_by_synth(Path(report.path)) for report in manifest.inputs)
