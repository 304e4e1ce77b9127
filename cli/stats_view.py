"""The tables `ngsim-graphs stats` prints, one function per table, from BuildStatistics."""

from __future__ import annotations

from rich.table import Table

from ngsim_cli.console import counted
from ngsim_graphs.schema import Split
from ngsim_graphs.statistics import BuildStatistics, Distribution

SPLIT_NAMES = tuple(split.value for split in Split)  # train, val, test


def _number(value: float | None, digits: int = 1) -> str:
    """`digits` decimals, none from 1,000 on (so that wide counts stay in an 80-column table)."""
    if value is None:
        return "-"
    text = f"{value:,.0f}" if abs(value) >= 1000 else f"{value:,.{digits}f}"
    return text.removeprefix("-") if text.strip("-0.,") == "" else text  # no "-0.000"


def _distribution_cells(d: Distribution, digits: int = 1, counts: bool = False) -> list[str]:
    """mean, min, p5, p50, p95, max; min and max without decimals for counts."""
    extreme = 0 if counts else digits
    return [
        _number(d.mean, digits),
        _number(d.min, extreme),
        *(_number(v, digits) for v in (d.p5, d.p50, d.p95)),
        _number(d.max, extreme),
    ]


def _table(title: str, first: list[str], right: list[str]) -> Table:
    table = Table(title=title, title_justify="left")
    for column in first:
        table.add_column(column, no_wrap=True)
    for column in right:
        table.add_column(column, justify="right")
    return table


DISTRIBUTION_COLUMNS = ["mean", "min", "p5", "p50", "p95", "max"]


def _graph_size_label(column: str) -> str:
    """A count column as the table names it: `n_spatial_edges` -> "spatial edges"."""
    return column.removeprefix("n_").replace("_", " ")


def _recordings_table(st: BuildStatistics) -> Table:
    table = _table(
        "Recordings (samples per split)",
        ["recording"],
        ["vehicles", "tracks", "rows 0.2 s", *SPLIT_NAMES],
    )
    for r in st.recordings:
        table.add_row(
            f"{r['location']} {r['period']}",
            f"{r['vehicles']:,}",
            f"{r['tracks']:,}",
            f"{r['grid_rows']:,}",
            *(f"{r['samples'].get(split, 0):,}" for split in SPLIT_NAMES),
        )
    return table


def _rows_table(st: BuildStatistics) -> Table:
    """Where the rows read went: each reason a row was dropped for, and what reached the tracks."""
    c = st.counts
    table = _table("Rows read (10 Hz) and where they went", ["rows"], ["count", "share"])
    lines = [
        ("read", c["rows_read"]),
        ("of other locations", c["rows_other_locations"]),
        ("an empty required field", c["rows_missing_values"]),
    ]
    lines += [(reason.replace("_", " "), n) for reason, n in c["rows_dropped"].items() if n]
    lines += [
        ("exact duplicates", c["exact_duplicates"]),
        ("conflicting duplicates", c["conflicting_duplicates"]),
    ]
    script = c.get("cslstm_rows")
    if script is not None:  # the cs-lstm protocol: what became of the rows CS-LSTM's script keeps
        lines += [
            ("kept by CS-LSTM's script (cs-lstm protocol)", script["kept"]),
            ("  of them on the grid (even frames)", script["on_grid"]),
            ("    without a track at their step: no sample", script["unmatched"]),
            ("of vehicles under 31 rows: left out", script["too_short"]),
        ]
    for label, n in lines:
        table.add_row(label, f"{n:,}", _share(n, c["rows_read"]))
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
            split,
            f"{n:,}",
            _share(n, total),
            f"{targets.targets:,}",
            f"{targets.full_future:,} ({_share(targets.full_future, targets.targets)})",
        )
    return table


def _graph_size_table(st: BuildStatistics) -> Table:
    table = _table("Graph size (all samples, exact)", ["split", "per graph"], DISTRIBUTION_COLUMNS)
    for split in SPLIT_NAMES:
        for column, sizes in st.graph_size[split].items():  # the build's count columns
            table.add_row(
                split, _graph_size_label(column), *_distribution_cells(sizes, counts=True)
            )
        table.add_section()
    return table


def _degree_table(st: BuildStatistics) -> Table:
    n_graphs = sum(d.sampled_graphs for d in st.node_degree.values())
    table = _table(
        f"Spatial in-degree per node (from {n_graphs:,} sampled graphs)",
        ["split"],
        ["graphs", "nodes", *DISTRIBUTION_COLUMNS],
    )
    for split in SPLIT_NAMES:
        graphs, d = st.node_degree[split].sampled_graphs, st.node_degree[split].spatial_in_degree
        table.add_row(split, f"{graphs:,}", f"{d.count:,}", *_distribution_cells(d, counts=True))
    return table


def _kinematics_table(st: BuildStatistics) -> Table:
    rows = st.kinematics["speed_mps"].count
    table = _table(
        f"Kinematics ({counted(rows, 'tracks row')})",
        ["quantity"],
        ["mean", "std", *DISTRIBUTION_COLUMNS[1:]],
    )
    for name, label, digits in (("speed_mps", "speed m/s", 2), ("heading_rad", "heading rad", 3)):
        d = st.kinematics[name]
        mean, *rest = _distribution_cells(d, digits)
        table.add_row(label, mean, _number(d.std, digits), *rest)
    return table


def _scaler_table(st: BuildStatistics) -> Table:
    table = _table("Scaler (MinMax, fitted on train)", ["quantity"], ["min", "max", "maps to"])
    for name, fitted in st.scaler.items():
        low, high = fitted["to"]
        table.add_row(
            name, _number(fitted["min"], 3), _number(fitted["max"], 3), f"({low:g}, {high:g})"
        )
    return table


def _config_table(st: BuildStatistics) -> Table:
    table = _table(f"Build config (sha256 {st.config_hash[:12]})", ["setting"], ["value"])
    flat = {}
    for name, value in st.config.items():  # nested settings (the physical limits) one per row
        flat.update(
            {f"{name}.{k}": v for k, v in value.items()}
            if isinstance(value, dict)
            else {name: value}
        )
    for name, value in flat.items():
        table.add_row(name, ", ".join(map(str, value)) if isinstance(value, list) else str(value))
    return table


STATS_TABLES = (
    _recordings_table,
    _rows_table,
    _splits_table,
    _graph_size_table,
    _degree_table,
    _kinematics_table,
    _scaler_table,
    _config_table,
)
