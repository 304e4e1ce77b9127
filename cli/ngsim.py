"""`ngsim-graphs`: synthesize NGSIM-format data, build graph datasets, and inspect a build."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.measure import Measurement
from rich.table import Table

from ngsim_cli.console import exit_on_input_error, progress_bar, stderr
from ngsim_graphs.building import BuildResult, run_build
from ngsim_graphs.builds import open_build
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.schema import RawFormat, SplitMode
from ngsim_graphs.statistics import MAX_DEGREE_GRAPHS, BuildStatistics, Distribution, build_statistics

app = typer.Typer(
    help="NGSIM US-101 / I-80 trajectories to spatial-temporal graph datasets.",
    no_args_is_help=True,
    add_completion=False,
)
stdout = Console()


def _print_table(table: Table) -> None:
    """A table on stdout; piped or redirected, at its natural width rather than cut to 80 columns."""
    if stdout.is_terminal:
        stdout.print(table)
    else:
        natural = Measurement.get(stdout, stdout.options.update(width=10_000), table).maximum
        Console(width=max(stdout.width, natural)).print(table)  # print() cannot widen the console


def _config_or_exit(factory, **kwargs):  # type: ignore[no-untyped-def]
    """The config dataclass, or one line on stderr and exit status 2 for an invalid option."""
    try:
        return factory(**kwargs)
    except ValueError as err:
        stderr.print(f"error: {err}", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(2) from None


@app.command()
def synth(
    out_dir: Annotated[Path, typer.Argument(help="Folder to write the files into.")],
    raw_format: Annotated[
        RawFormat, typer.Option("--format", help="portal: one combined CSV; csv/txt: one file per period.")
    ] = RawFormat.TXT,
    recordings: Annotated[int, typer.Option(help="How many of the six NGSIM periods (1-6).")] = 6,
    minutes: Annotated[float, typer.Option(help="Length of each recording, minutes.")] = 15.0,
    seed: Annotated[int, typer.Option(help="Random seed; the same seed gives the same bytes.")] = 0,
    quirks: Annotated[
        bool, typer.Option(help="Inject the quirks of real exports (BOM, CRLF, \"1,156\", duplicates, gaps, ...).")
    ] = False,
) -> None:
    """Write synthetic NGSIM-shaped trajectories (simulated traffic, NOT real NGSIM data)."""
    from ngsim_graphs.synthesis import write_synthetic  # the simulator loads only when used

    config = _config_or_exit(
        SynthConfig, raw_format=raw_format, recordings=recordings, minutes=minutes, seed=seed, quirks=quirks
    )
    with progress_bar() as progress:
        paths = write_synthetic(out_dir, config, lambda what: progress(what, 0, 0))
    for path in paths:
        stdout.print(f"{path}  {path.stat().st_size / 1e6:.1f} MB")


SPLIT_NAMES = ("train", "val", "test")


def _summary_table(result: BuildResult) -> Table:
    table = Table(title=f"build {result.out_dir}")
    table.add_column("location", no_wrap=True)
    table.add_column("period", no_wrap=True)
    for column in ("rows", "dups", "conflicts", "gaps", "tracks", "grid rows", *SPLIT_NAMES):
        table.add_column(column, justify="right")
    samples = {(r["location"], r["period"]): r["samples"] for r in result.manifest["recordings"]}
    for r in result.recordings:
        per_split = samples.get((r.location, r.period), {})
        table.add_row(
            r.location,
            r.period,
            *(f"{v:,}" for v in (r.rows, r.exact_duplicates, r.conflicting_duplicates, r.gaps, r.tracks, r.grid_rows)),
            *(f"{per_split.get(split, 0):,}" for split in SPLIT_NAMES),
        )
    return table


@app.command()
def build(
    raw_paths: Annotated[list[Path], typer.Argument(help="NGSIM files, or folders to search for them.")],
    out: Annotated[Path, typer.Option("--out", help="Output directory of the build.")],
    locations: Annotated[str, typer.Option(help="Comma-separated locations to keep.")] = "us-101,i-80",
    stride_s: Annotated[
        float,
        typer.Option(help="Time between the starts of two windows of one ego track, s: a multiple of the "
                     "0.2 s grid step (8: non-overlapping 8 s windows; 0.2: a window at every step)."),
    ] = 8.0,
    d_sense_m: Annotated[
        float, typer.Option(help="A vehicle at most this far from the ego at a history step is a node, m.")
    ] = 50.0,
    d_min_m: Annotated[
        float,
        typer.Option(help="Two actor nodes at most this far apart share spatial edges, m (0: only ego-actor "
                     "edges)."),
    ] = 25.0,
    split: Annotated[
        SplitMode,
        typer.Option(help="How ego windows are divided 70/10/20 into train/val/test: by ego Vehicle_ID "
                     "per recording, by contiguous blocks of time, or at random by ego track."),
    ] = SplitMode.VEHICLE,
    seed: Annotated[int, typer.Option(help="Seed of the random split (other splits ignore it).")] = 0,
    ego_target: Annotated[
        bool, typer.Option(help="Also predict the ego (by default only the actors at the present step).")
    ] = False,
    overwrite: Annotated[bool, typer.Option(help="Replace a non-empty output directory.")] = False,
    min_heading_speed_mps: Annotated[
        float, typer.Option(help="Below this speed the last heading is held, m/s.")
    ] = 2.0,
    heading_smoothing_s: Annotated[
        float, typer.Option(help="Centred moving average of positions before the heading, s.")
    ] = 1.0,
) -> None:
    """Read raw NGSIM files (any of the three formats) and write the graph dataset."""
    config = _config_or_exit(
        BuildConfig,
        locations=tuple(name.strip().lower() for name in locations.split(",") if name.strip()),
        stride_s=stride_s,
        d_sense_m=d_sense_m,
        d_min_m=d_min_m,
        split=split,
        seed=seed,
        ego_is_target=ego_target,
        min_heading_speed_mps=min_heading_speed_mps,
        heading_smoothing_s=heading_smoothing_s,
    )
    with exit_on_input_error(), progress_bar() as progress:
        result = run_build(raw_paths, out, config, overwrite=overwrite, progress=progress)
    for skipped in result.skipped_files:
        stdout.print(f"skipped (not NGSIM): {skipped}")
    _print_table(_summary_table(result))
    counts, splits = result.manifest["counts"], result.manifest["splits"]
    stdout.print(
        f"{counts['rows_read']:,} rows read, {counts['rows_other_locations']:,} of other locations, "
        f"{counts['rows_missing_values']:,} with empty required fields dropped."
    )
    stdout.print(
        "samples: " + ", ".join(f"{splits.get(name, 0):,} {name}" for name in SPLIT_NAMES)
        + f" ({counts['samples']:,} in all)."
    )


def _number(value: float | None, digits: int = 1) -> str:
    """`digits` decimals, none from 1,000 on (so that wide counts stay in an 80-column table)."""
    if value is None:
        return "-"
    text = f"{value:,.0f}" if abs(value) >= 1000 else f"{value:,.{digits}f}"
    return text.removeprefix("-") if text.strip("-0.,") == "" else text  # no "-0.000"


def _distribution_cells(d: Distribution, digits: int = 1, counts: bool = False) -> list[str]:
    """mean, min, p5, p50, p95, max; min and max without decimals for counts."""
    extreme = 0 if counts else digits
    return [_number(d.mean, digits), _number(d.min, extreme), *(_number(v, digits) for v in (d.p5, d.p50, d.p95)),
            _number(d.max, extreme)]  # fmt: skip


def _table(title: str, first: list[str], right: list[str]) -> Table:
    table = Table(title=title, title_justify="left")
    for column in first:
        table.add_column(column, no_wrap=True)
    for column in right:
        table.add_column(column, justify="right")
    return table


DISTRIBUTION_COLUMNS = ["mean", "min", "p5", "p50", "p95", "max"]
GRAPH_SIZE_LABELS = {
    "n_nodes": "nodes", "n_spatial_edges": "spatial edges", "n_temporal_edges": "temporal edges",
    "n_targets": "targets",
}  # fmt: skip


def _recordings_table(st: BuildStatistics) -> Table:
    table = _table("Recordings (samples per split)", ["recording"],
                   ["vehicles", "tracks", "rows 0.2 s", *SPLIT_NAMES])  # fmt: skip
    for r in st.recordings:
        table.add_row(
            f"{r['location']} {r['period']}", f"{r['vehicles']:,}", f"{r['tracks']:,}", f"{r['grid_rows']:,}",
            *(f"{r['samples'].get(split, 0):,}" for split in SPLIT_NAMES),
        )  # fmt: skip
    return table


def _share(part: int, whole: int) -> str:
    return f"{part / whole:.1%}" if whole else "-"


def _splits_table(st: BuildStatistics) -> Table:
    total = sum(st.samples.values())
    full_future = f"targets with full {st.future_horizon_s:g} s future"
    table = _table("Splits", ["split"], ["samples", "share", "targets", full_future])
    for split in SPLIT_NAMES:
        n, targets = st.samples[split], st.targets[split]
        table.add_row(
            split, f"{n:,}", _share(n, total), f"{targets.targets:,}",
            f"{targets.full_future:,} ({_share(targets.full_future, targets.targets)})",
        )  # fmt: skip
    return table


def _graph_size_table(st: BuildStatistics) -> Table:
    table = _table("Graph size (all samples, exact)", ["split", "per graph"], DISTRIBUTION_COLUMNS)
    for split in SPLIT_NAMES:
        for column, label in GRAPH_SIZE_LABELS.items():
            table.add_row(split, label, *_distribution_cells(st.graph_size[split][column], counts=True))
        table.add_section()
    return table


def _degree_table(st: BuildStatistics) -> Table:
    n_graphs = sum(d.sampled_graphs for d in st.node_degree.values())
    table = _table(f"Spatial in-degree per node (from {n_graphs:,} sampled graphs)",
                   ["split"], ["graphs", "nodes", *DISTRIBUTION_COLUMNS])  # fmt: skip
    for split in SPLIT_NAMES:
        graphs, d = st.node_degree[split].sampled_graphs, st.node_degree[split].spatial_in_degree
        table.add_row(split, f"{graphs:,}", f"{d.count:,}", *_distribution_cells(d, counts=True))
    return table


def _kinematics_table(st: BuildStatistics) -> Table:
    rows = st.kinematics["speed_mps"].count
    table = _table(f"Kinematics ({rows:,} tracks rows)", ["quantity"], ["mean", "std", *DISTRIBUTION_COLUMNS[1:]])
    for name, label, digits in (("speed_mps", "speed m/s", 2), ("heading_rad", "heading rad", 3)):
        d = st.kinematics[name]
        mean, *rest = _distribution_cells(d, digits)
        table.add_row(label, mean, _number(d.std, digits), *rest)
    return table


def _scaler_table(st: BuildStatistics) -> Table:
    table = _table("Scaler (MinMax, fitted on train)", ["quantity"], ["min", "max", "maps to"])
    for name, fitted in st.scaler.items():
        low, high = fitted["to"]
        table.add_row(name, _number(fitted["min"], 3), _number(fitted["max"], 3), f"({low:g}, {high:g})")
    return table


def _config_table(st: BuildStatistics) -> Table:
    table = _table(f"Build config (sha256 {st.config_hash[:12]})", ["setting"], ["value"])
    for name, value in st.config.items():
        table.add_row(name, ", ".join(map(str, value)) if isinstance(value, list) else str(value))
    return table


STATS_TABLES = (
    _recordings_table, _splits_table, _graph_size_table, _degree_table, _kinematics_table, _scaler_table,
    _config_table,
)  # fmt: skip


def _write_plots(values, folder: Path) -> list[Path]:  # type: ignore[no-untyped-def]
    """The PNG histograms, or one line on stderr and exit status 1 where the folder is unusable."""
    from ngsim_graphs.plotting import write_histograms  # matplotlib loads only when plotting

    try:
        return write_histograms(values, folder)
    except OSError as err:
        stderr.print(f"error: {folder}: cannot write plots: {err.strerror or err}", markup=False,
                     highlight=False, soft_wrap=True)  # fmt: skip
        raise typer.Exit(1) from None


@app.command()
def stats(
    build_dir: Annotated[Path, typer.Argument(help="A finished build directory.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON document, nothing else.")] = False,
    plots: Annotated[
        Path | None, typer.Option("--plots", help="Folder to write PNG histograms into (created).")
    ] = None,
    degree_graphs: Annotated[
        int, typer.Option(min=1, help="Graphs per split induced (at random) for the node-degree statistics.")
    ] = MAX_DEGREE_GRAPHS,
    seed: Annotated[int, typer.Option(help="Seed of the random choice of those graphs.")] = 0,
) -> None:
    """Check a build before training: samples, graph sizes, degrees, kinematics, scaler, config."""
    with exit_on_input_error():
        opened = open_build(build_dir)
        try:
            statistics, values = build_statistics(opened, degree_graphs, seed)
        except OSError as err:  # a file listed in the manifest is gone
            raise NgsimInputError(build_dir, f"incomplete build: {err}") from None
    written = _write_plots(values, plots) if plots is not None else []
    if as_json:
        document = statistics.to_dict() | {"plots": [str(path) for path in written]}
        typer.echo(json.dumps(document, indent=2))
        return
    for make_table in STATS_TABLES:
        _print_table(make_table(statistics))
    for path in written:
        stdout.print(f"wrote {path}")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
