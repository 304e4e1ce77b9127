"""`ngsim-graphs build`: raw files to a finished, self-describing dataset directory.

A data source (`sources`) reads each input file and stages its rows per recording and part of
its vehicles; each recording is then cleaned into its tracks table, a part at a time, and
built: frame arrays, ego windows, splits, and every sample's counts and its share of the
scaler's ranges (`tasks`). The files and then the recordings go to `--jobs` worker processes
(`workers`; `engine.stages` runs each stage over them); what depends on the order of the
recordings (track numbers, the samples tables, the manifest) is decided between the stages, so
that any number of jobs gives the same build.

Several builds of the same files (`run_builds`: the paper's d_min of 0, 25 and 50 m) share
the reading and the cleaning, which read only the config's SHARED_FIELDS: the files are staged
and the recordings cleaned once, into the first build's staging, and each build's recordings
are built from those cleaned tracks into its own directory, which then lands on its own.

Memory stays bounded per job, whatever the size of a file or recording: a task holds a batch of
a file's rows, a group of a recording's vehicles, or a range of a recording's grid rows and
proximity pairs, and of a whole recording only its samples and an index or two per grid row
(`tasks`; cs-lstm: also its raw rows' five columns). A recording's samples are staged by its
task; this process writes the samples tables from them a recording at a time, and keeps of each
recording only its counts and scaler ranges.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass, replace
from functools import reduce
from pathlib import Path

from ngsim_graphs import edges, landing, layout
from ngsim_graphs.budget import available_cores
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.engine import stages, summary
from ngsim_graphs.engine.stages import BuildProgress, Inputs
from ngsim_graphs.engine.tasks import RecordingOutput
from ngsim_graphs.engine.workers import Workers, one_malloc_arena
from ngsim_graphs.manifest import Manifest
from ngsim_graphs.protocols import PROTOCOLS, check_protocol_locations
from ngsim_graphs.scaling import MinMaxScaler
from ngsim_graphs.sources.contract import FileReport, RecordingReport
from ngsim_graphs.sources.limits import PhysicalLimits
from ngsim_graphs.sources.registry import check_locations
from ngsim_graphs.synth.marker import mixed_inputs_warning

__all__ = [
    "SHARED_FIELDS",
    "BuildProgress",
    "BuildResult",
    "check_config",
    "run_build",
    "run_builds",
]

BuildTarget = tuple[Path, BuildConfig]  # an output folder and the config of its build
RawPaths = str | os.PathLike[str] | Sequence[str | os.PathLike[str]]  # a file or folder, or several
# The fields of BuildConfig that reading and cleaning read (the sources' read_file,
# vehicle_tracks and recording_report, with the property they use: smoothing_window_steps):
# builds alike in these share those stages (`run_builds`).
SHARED_FIELDS = (
    "locations",
    "time_step_s",
    "heading_smoothing_s",
    "min_heading_speed_mps",
)


@dataclass(frozen=True)
class BuildResult:
    """What a finished build holds; the same facts as its manifest."""

    out_dir: Path
    files: tuple[FileReport, ...]
    skipped_files: tuple[str, ...]
    recordings: tuple[RecordingReport, ...]
    manifest: Manifest
    warnings: tuple[str, ...] = ()  # also in the manifest: splits that are empty or tiny


def _finish(
    target: BuildTarget,
    root: Path,
    inputs: Inputs,
    outputs: list[RecordingOutput],
    progress: BuildProgress,
) -> BuildResult:
    """A built target's samples tables and manifest written into `root`, the manifest last."""
    out_dir, config = target
    source, file_reports, skipped, synthetic = (
        inputs.source, inputs.reports, inputs.skipped, inputs.synthetic
    )  # fmt: skip
    scaler = reduce(MinMaxScaler.joined, [o.train_ranges for o in outputs])
    progress("writing samples", len(outputs), len(outputs))
    samples = stages.write_samples(root, outputs, config)
    mixed = mixed_inputs_warning([file.path for file in file_reports], synthetic)
    warnings = summary.warnings(outputs, config, file_reports) + ([mixed] if mixed else [])
    manifest = summary.manifest(
        source.name,
        config,
        source.limits,
        file_reports,
        outputs,
        samples,
        scaler,
        warnings,
        skipped,
    )
    manifest = replace(
        manifest, synthetic=len(synthetic) == len(file_reports), synthetic_inputs=synthetic
    )
    manifest = layout.write_manifest(root, manifest)
    return BuildResult(
        out_dir=out_dir,
        files=tuple(file_reports),
        skipped_files=tuple(skipped),
        recordings=tuple(o.report for o in outputs),
        manifest=manifest,
        warnings=tuple(warnings),
    )


def check_config(config: BuildConfig) -> None:
    """ValueError where `config` names what this ngsim-graphs cannot build: a location no source
    knows, one its protocol does not read, an edge type not in `edges.EDGE_TYPES`."""
    check_locations(config.locations)
    check_protocol_locations(config)
    edges.types_of(config.edge_types)


def _check_targets(raw_paths: list[Path], targets: list[BuildTarget]) -> None:
    """Refuse builds that cannot share their reading and cleaning (a config that differs in a
    field of SHARED_FIELDS), or whose outputs overlap each other or an input."""
    if not targets:
        raise ValueError("no build to make: name at least one output folder and config")
    first_out, first = targets[0]
    for out_dir, config in targets[1:]:
        for name in SHARED_FIELDS:
            if getattr(config, name) != getattr(first, name):
                raise ValueError(
                    f"{name} differs between the builds for {first_out} ({getattr(first, name)}) "
                    f"and {out_dir} ({getattr(config, name)}): builds made together share the "
                    f"reading and cleaning of the inputs, which read it; build them apart"
                )
    for out_dir, config in targets:
        check_config(config)  # before any work
        landing.check_outside_inputs(out_dir, raw_paths)
    landing.check_apart([out_dir for out_dir, _ in targets])


def _labelled(progress: BuildProgress, out_dir: Path, several: bool) -> BuildProgress:
    """`progress` with each stage named by its build's `out_dir` where builds are made together."""
    if not several:
        return progress
    label = f" ({out_dir.name})"
    return lambda what, done, total: progress(f"{what}{label}", done, total)


def _raw_paths(raw_paths: RawPaths) -> list[Path]:
    """The inputs as Paths: one path alone (never a str read as its characters) or several."""
    if isinstance(raw_paths, str | os.PathLike):
        return [Path(raw_paths)]
    return [Path(path) for path in raw_paths]


def run_builds(
    raw_paths: RawPaths,
    targets: Sequence[tuple[str | os.PathLike[str], BuildConfig]],
    overwrite: bool = False,
    progress: BuildProgress | None = None,
    strict: bool = False,
    dataset: str | None = None,
    jobs: int | None = 1,
    limits: PhysicalLimits | None = None,
) -> list[BuildResult]:
    """Read every raw file under `raw_paths` and write a finished build into each target's
    out_dir, as `run_build` does for each (byte for byte its output), reading and cleaning the
    inputs once for all, with one source's physical limits (`limits`, or the source's own).

    The targets' configs may differ only in the fields that reading and cleaning do not read
    (not in SHARED_FIELDS: d_min_m, d_sense_m, the windows, the split, the protocol); their
    out_dirs must be apart from each other and from the inputs. Every out_dir is checked and
    locked before anything is read; the files are read and staged and the recordings cleaned
    into the first target's staging, which every target's build reads. Once every target's
    recordings are built, and each has samples, each target lands on its own as soon as its
    samples and manifest are written, in the order given: a failure or Ctrl-C leaves the
    targets that had landed as finished builds and every other out_dir as it was. Raises
    ValueError for configs that cannot share the reading (naming the field), and as
    `run_build` does.
    """
    raw_paths = _raw_paths(raw_paths)
    targets = [(Path(out_dir), config) for out_dir, config in targets]
    _check_targets(raw_paths, targets)  # before anything is read or written
    workers = Workers(available_cores() if jobs is None else jobs)  # checks jobs >= 1
    if workers.jobs == 1:  # the tasks run in this process
        one_malloc_arena()
    report_progress = progress or (lambda _what, _done, _total: None)
    several = len(targets) > 1
    shared = targets[0][1]  # its SHARED_FIELDS are every target's
    with ExitStack() as landings:
        # One stack per target, closed when it lands; the outer one removes those left.
        stacks = [landings.enter_context(ExitStack()) for _ in targets]
        roots = [
            stack.enter_context(landing.build_directory(out_dir, overwrite))
            for stack, (out_dir, _) in zip(stacks, targets, strict=True)
        ]
        scratch = roots[0]
        with workers:  # the workers end here: what they held goes back before the writing
            inputs = stages.read_inputs(
                raw_paths, dataset, limits, shared, scratch, report_progress, strict, workers
            )
            source, file_reports, staged = inputs.source, inputs.reports, inputs.staged
            for _, config in targets:
                stages.check_recordings(staged, file_reports, PROTOCOLS[config.protocol])
            reports = stages.clean_recordings(
                source, staged, shared, scratch, file_reports, report_progress, strict, workers
            )
            built = []  # each target's recordings, built from the same cleaned tracks
            for (out_dir, config), root in zip(targets, roots, strict=True):
                labelled = _labelled(report_progress, out_dir, several)
                built.append(
                    stages.build_recordings(
                        staged, reports, scratch, config, root, labelled, workers
                    )
                )
        for (_, config), outputs in zip(targets, built, strict=True):
            frames = inputs.source.frames_per_step(config.time_step_s)
            summary.check_some_samples(outputs, config, raw_paths, frames)
        results = []
        for target, root, outputs, stack in zip(targets, roots, built, stacks, strict=True):
            labelled = _labelled(report_progress, target[0], several)
            results.append(_finish(target, root, inputs, outputs, labelled))
            stack.close()  # lands this target's out_dir
    return results


def run_build(
    raw_paths: RawPaths,
    out_dir: str | os.PathLike[str],
    config: BuildConfig,
    overwrite: bool = False,
    progress: BuildProgress | None = None,
    strict: bool = False,
    dataset: str | None = None,
    jobs: int | None = 1,
    limits: PhysicalLimits | None = None,
) -> BuildResult:
    """Read every raw file under `raw_paths` (a file or folder, or several) and write the
    finished build into `out_dir`.

    `dataset` names the source (`sources.registry.SOURCES`); by default it is told from the files.
    `limits` replaces the source's physical limits (`Source.limits`: what a raw row may hold,
    its frame ids in its own frames); the manifest records those applied.
    The same files named in any order, or found in folders, give the same build, byte for byte.
    `jobs` > 1 reads the files and builds the recordings in that many worker processes (None:
    one per core this process may use); the output is the same for any number. The processes
    that run the tasks keep to one malloc arena (`workers.worker_environment`). With one job,
    and for a stage of a single task, the tasks run in this process; with one job it asks for
    one arena for the rest of its life (`workers.one_malloc_arena`: only threads started after
    keep to it). The workers are started with multiprocessing's "spawn": a script that builds
    with jobs > 1 must do so under `if __name__ == "__main__":`.
    Raises ValueError for a location no source knows, NgsimInputError for unusable input and
    NgsimOutputError for an `out_dir` that must
    not be written (an input, another program's folder, another build's) or cannot be (a full
    disk); `out_dir` is then left as it was.
    """
    [result] = run_builds(
        raw_paths, [(out_dir, config)], overwrite, progress, strict, dataset, jobs, limits
    )
    return result
