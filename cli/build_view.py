"""What `ngsim-graphs build` prints of a finished build: a table per recording, what was dropped
and why, the samples per split, and the warnings."""

from __future__ import annotations

from rich.table import Table

from ngsim_cli.console import counted, print_line, print_table, print_warning, stdout
from ngsim_cli.stats_view import SPLIT_NAMES
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.pipeline import BuildResult
from ngsim_graphs.schema import DropReason, SplitMode
from ngsim_graphs.sources.registry import drop_descriptions, label


def print_build_report(result: BuildResult) -> None:
    """The build's report on stdout (its warnings on stderr)."""
    for skipped in result.skipped_files:
        print_line(f"skipped (not {label(result.manifest.dataset)}): {skipped}")
    print_table(_summary_table(result))
    counts, splits = result.manifest.counts, result.manifest.splits
    stdout.print(
        f"{counted(counts.rows_read, 'row')} read, {counts.rows_other_locations:,} of other locations, "
        f"{counts.rows_missing_values:,} with empty required fields dropped."
    )
    for line in _dropped_lines(result):
        stdout.print(line, markup=False, highlight=False, soft_wrap=True)
    script = counts.cslstm_rows
    if script is not None:
        stdout.print(
            f"cs-lstm protocol: CS-LSTM's script keeps {counted(script.kept, 'row')}, {script.on_grid:,} "
            f"on the {result.manifest.config.time_step_s:g} s grid (one per vehicle and even frame); "
            f"{script.unmatched:,} of those "
            "have no track at their step (cleaning removed the row) and give no sample; "
            f"{counted(script.too_short, 'row')} of vehicles under 31 rows left out (the script stops on "
            "them).",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    for warning in result.warnings:
        print_warning(warning)
    shares = " / ".join(
        f"{splits.get(name, 0) / max(1, counts.samples):.0%}" for name in SPLIT_NAMES
    )
    stdout.print(
        "samples: "
        + ", ".join(f"{splits.get(name, 0):,} {name}" for name in SPLIT_NAMES)
        + f" ({counts.samples:,} in all; shares {shares}: {split_words(result.manifest.config)}).",
        markup=False,
        highlight=False,
    )


def split_words(config: BuildConfig) -> str:
    """Why the shares of samples are not the split's fractions (ngsim_graphs.splits): what each
    split mode divides, and why samples do not follow it."""
    train, val, _ = config.split_fractions
    if config.split is SplitMode.VEHICLE:
        return (
            f"the vehicle split cuts each recording's Vehicle_IDs at {train:.0%} and "
            f"{train + val:.0%} of its largest, not its samples, and vehicles give different "
            "numbers of samples: the last IDs entered last, and the recording's end cuts their "
            "tracks short"
        )
    if config.split is SplitMode.TIME:
        return (
            f"the time split cuts each recording's windows at {train:.0%} and {train + val:.0%} "
            "by present time, and drops those within a window after each cut"
        )
    fractions = " / ".join(f"{f:.0%}" for f in config.split_fractions)
    return (
        f"the random split draws {fractions} of the ego tracks, not of the samples, and tracks "
        "give different numbers of samples"
    )


def _summary_table(result: BuildResult) -> Table:
    table = Table(title=f"build {result.out_dir}")
    table.add_column("location", no_wrap=True)
    table.add_column("period", no_wrap=True)
    for column in ("rows", "dups", "conflicts", "gaps", "tracks", "grid rows", *SPLIT_NAMES):
        table.add_column(column, justify="right")
    samples = {(r.location, r.period): r.samples for r in result.manifest.recordings}
    for r in result.recordings:
        per_split = samples.get((r.location, r.period), {})
        table.add_row(
            r.location,
            r.period,
            *(
                f"{v:,}"
                for v in (
                    r.rows,
                    r.exact_duplicates,
                    r.conflicting_duplicates,
                    r.gaps,
                    r.tracks,
                    r.grid_rows,
                )
            ),
            *(f"{per_split.get(split, 0):,}" for split in SPLIT_NAMES),
        )
    return table


def _dropped_lines(result: BuildResult) -> list[str]:
    """One line per reason rows were dropped for, with the first place it happened."""
    lines = []
    descriptions = drop_descriptions(result.manifest.dataset)
    for reason, n in result.manifest.counts.rows_dropped.items():
        if not n:
            continue
        if reason == DropReason.POSITION_OUTLIER.value:
            first = min(
                f"{r.first_outlier.file}, line {r.first_outlier.line}"
                for r in result.manifest.recordings
                if r.first_outlier
            )
        else:
            first = next(
                f"{f.path}, line {f.first_dropped_line[reason]}"
                for f in result.files
                if reason in f.first_dropped_line
            )
        noun = "row" if n == 1 else "rows"
        lines.append(
            f"dropped {n:,} {noun}: {descriptions.get(reason, reason.replace('_', ' '))} (first: {first})."
        )
    jumps = result.manifest.counts.position_jumps
    if jumps:
        limits = result.manifest.limits  # those its source applied
        limit = "the jump limit" if limits is None else f"{limits.max_jump_m:g} m"
        noun = "jump" if jumps == 1 else "jumps"
        lines.append(
            f"split tracks at {jumps:,} position {noun} of more than {limit} between frames."
        )
    return lines
