"""synth's marker, read back: which files `ngsim-graphs synth` wrote, and so which builds are of
simulated data.

Every folder synth fills carries MARKER_NAME (written by `synth.formats`), which says the data are
simulated and lists the files synth wrote there, one `- NAME` line each, NAME relative to the
folder. A build looks at its inputs once, when it reads them: an input is synth's when a marker
in its folder or the folder above (synth's `<location>/<file>` layouts) lists it. The manifest
records the answer (`synthetic`: every input is synth's; `synthetic_inputs`: those that are), so
that it holds wherever the inputs go later, and a build that mixes synth's files with others
says so in a warning naming both. Everything that reports on a build (`stats --json`, `show`,
`aigem evaluate --json` and `--plots`, `fit`'s curves) says so with `synthetic_build`, which
reads the manifest (a manifest made before the record: the markers beside its inputs, as then).

Only the marker is read (no simulator is imported): a few small files, once per build.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
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


def synthetic_inputs(paths: Iterable[str]) -> tuple[str, ...]:
    """The inputs among `paths` (absolute) that synth wrote (`written_by_synth`), in order."""
    return tuple(path for path in paths if written_by_synth(Path(path)))


def mixed_inputs_warning(paths: Sequence[str], synthetic: Sequence[str]) -> str | None:
    """A warning naming the inputs synth wrote and those it did not, where both are among the
    inputs `paths`; None where all or none are synth's."""
    measured = [path for path in paths if path not in set(synthetic)]
    if not synthetic or not measured:
        return None
    return (
        f"the inputs mix synthetic and other data: {_some(synthetic)} written by `ngsim-graphs "
        f"synth` ({MARKER_NAME} lists them), {_some(measured)} not; the build is recorded as "
        "not synthetic, its manifest's synthetic_inputs names the synthetic ones"
    )


def _some(paths: Sequence[str]) -> str:
    shown = ", ".join(paths[:3]) + (f" and {len(paths) - 3} more" if len(paths) > 3 else "")
    return f"{len(paths)} ({shown})"


def synthetic_build(manifest: Manifest) -> bool:
    """Whether the build of `manifest` is of synthetic data, as its manifest records it (every
    input written by synth); for a manifest made before that record, whether synth's markers
    beside its inputs list any of them (they may have moved since)."""
    if manifest.synthetic is not None:
        return manifest.synthetic
    return any(written_by_synth(Path(report.path)) for report in manifest.inputs)


def synthetic_inputs_of(manifest: Manifest) -> tuple[str, ...]:
    """The inputs of the build of `manifest` that synth wrote, as its manifest records them (a
    manifest made before that record: as synth's markers beside them say now)."""
    if manifest.synthetic is not None:
        return manifest.synthetic_inputs
    return synthetic_inputs(report.path for report in manifest.inputs)
