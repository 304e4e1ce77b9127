"""How `aigem evaluate` prints its result: a table per region whose columns are the metrics that
aigem.metrics reports (METRICS), the table of all actors with each number's 95 % interval on a
second line and AiGem's difference to constant velocity, the targets counted, the protocol, and
the paper's table."""

from __future__ import annotations

from rich.table import Table

from aigem.evaluation.results import Evaluation, paper_rows
from aigem.intervals import Interval, SampleIntervals
from aigem.metrics import REGIONS, table_columns
from aigem.paper.report_cells import seconds_words
from aigem.runs.course import training_line, training_words
from ngsim_cli.console import counted, print_table, print_warning, stdout
from ngsim_graphs.synth.marker import SYNTHETIC_LABEL

DIFFERENCE = "AiGem - constant velocity"  # the row of the paired differences
PARAMS = "params (K)"  # the parameters' column: thousands, as the paper's Table 1 counts them


def metrics_table(
    title: str,
    rows: dict[str, dict],
    seconds: int,
    intervals: dict[str, dict[str, Interval]] | None = None,
) -> Table:
    """One row per model of `rows` (name -> metric key -> value, metres; "params_k"), a column
    per metric of aigem.metrics over `seconds` whole seconds; "-" where a row has no value.
    `intervals` (row name -> metric key -> Interval): a second, dim line under a row's value
    with its interval (interval_words)."""
    columns = table_columns(seconds)
    table = Table(title=title)
    table.add_column("model", justify="left")
    for _, label in columns:
        table.add_column(label, justify="right")
    table.add_column(PARAMS, justify="right")
    fmt = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    for name, row in rows.items():
        bounds = (intervals or {}).get(name, {})
        values = [fmt(row.get(key)) for key, _ in columns]
        if bounds:
            values = [
                value + (f"\n[dim]{interval_words(bounds[key])}[/dim]" if key in bounds else "")
                for value, (key, _) in zip(values, columns, strict=True)
            ]
        table.add_row(name, *values, str(row.get("params_k", "")))
    return table


def interval_words(interval: Interval) -> str:
    """An interval as its bounds' distances from its value, to the table's 2 decimals: "±0.04"
    where they are alike, "+0.05/-0.03" where not, "0.10 to 0.30" where the value lies outside
    (a percentile interval need not hold it); "" where it has no bounds."""
    if not interval.known:
        return ""
    if not interval.low <= interval.value <= interval.high:
        return f"{interval.low:.2f} to {interval.high:.2f}"
    above, below = f"{interval.high - interval.value:.2f}", f"{interval.value - interval.low:.2f}"
    return f"±{above}" if above == below else f"+{above}/-{below}"


def _rows(
    model: dict, baseline: dict, intervals: SampleIntervals | None
) -> tuple[dict[str, dict], dict[str, dict[str, Interval]] | None]:
    """A region's rows (AiGem, constant velocity, and with `intervals` their difference) and
    each row's intervals."""
    rows = {"AiGem (this run)": model, "constant velocity": baseline}
    if intervals is None:
        return rows, None
    paired = intervals.metrics
    rows[DIFFERENCE] = {key: p.difference.value for key, p in paired.items()}
    return rows, {
        "AiGem (this run)": {key: p.model for key, p in paired.items()},
        "constant velocity": {key: p.constant_velocity for key, p in paired.items()},
        DIFFERENCE: {key: p.difference for key, p in paired.items()},
    }


def print_evaluation(result: Evaluation) -> None:
    """The tables and lines of `aigem evaluate` without --json; each of the run's tables says
    how many of its epochs the model trained, and an unfinished run how to continue it."""
    trained = training_words(result.training)
    seconds = sum(key.startswith("rmse_") for key in result.model["all"])
    empty = [
        region
        for region in REGIONS[1:]
        if not any(result.model[region][f"n_{s}s"] for s in range(1, seconds + 1))
    ]
    for region in REGIONS:
        if region in empty:
            continue
        ours = {**result.model[region], "params_k": round(result.parameters / 1000, 1)}
        shown = result.intervals if region == "all" else None  # intervals: all actors only
        rows, intervals = _rows(ours, result.constant_velocity[region], shown)
        title = f"{result.split} split, {region} actors (metres); {trained}"
        print_table(metrics_table(title, rows, seconds, intervals))
        if shown is not None:
            stdout.print(_intervals_line(shown), highlight=False, soft_wrap=True)
    if empty:
        stdout.print(f"No {' or '.join(empty)} actors among the targets: no table for them.")
    counts = ", ".join(f"{s} s: {result.model['all'][f'n_{s}s']:,}" for s in range(1, seconds + 1))
    stdout.print(f"{counted(result.samples, 'sample')}; evaluated actors per horizon: {counts}")
    stdout.print(
        f"Protocol: {result.protocol} ({result.protocol_description})",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    _print_sources(result, seconds)
    print_table(metrics_table("the paper's table (NGSIM US-101 + I-80)", paper_rows(), 5))
    other = (
        "" if result.same_build else " (not the run's build; inputs scaled with the run's scaler)"
    )
    kind = (
        f", a build of {SYNTHETIC_LABEL}: synthetic results, not comparable to the paper's NGSIM numbers"
        if result.synthetic
        else ""
    )
    stdout.print(f"These numbers come from {result.build_dir}{other}{kind}.")
    stdout.print(
        f"{training_line(result.training)}.", markup=False, highlight=False, soft_wrap=True
    )
    warn_unfinished(result)


def _intervals_line(intervals: SampleIntervals) -> str:
    """What the second lines of the table of all actors are."""
    return (
        f"Under each number: its 95 % interval (percentile bootstrap: "
        f"{counted(intervals.resamples, 'resample')} of the {counted(intervals.samples, 'sample')}"
        f", each sample's actors drawn together; seed {intervals.seed}); {DIFFERENCE} on the "
        "same resamples. --json gives the bounds."
    )


def warn_unfinished(result: Evaluation) -> None:
    """One warning on stderr where the run is unfinished (also beside --json)."""
    if result.training is not None and not result.training["finished"]:
        line = training_line(result.training)
        print_warning(f"these scores are of an unfinished run: {line}")


def _print_sources(result: Evaluation, seconds: int) -> None:
    """Which model of the run each number comes from (named by its horizon)."""
    stdout.print(sources_line(result, seconds), markup=False, highlight=False, soft_wrap=True)


def sources_line(result: Evaluation, seconds: int) -> str:
    """In words, which model each number comes from: a run's one model, or per model of a
    multi-horizon run the seconds whose RMSE it gives (the first model that reaches them)."""
    horizon_s = result.horizons_s[-1]
    paper = "" if horizon_s == 5 else ", the paper's over 5 s"
    whole = f"ADE and FDE over {horizon_s:g} s"
    if len(result.members) == 1:
        return (
            f"One model, trained for {horizon_s:g} s: every number comes from it (RMSE at "
            f"{seconds_words(range(1, seconds + 1))}; {whole}{paper}). Constant velocity on the "
            "same targets."
        )
    model = dict(zip(result.members, result.horizons_s, strict=True))
    at: dict[float, list[int]] = {}  # a model's horizon -> the seconds whose RMSE it gives
    for second in range(1, seconds + 1):
        at.setdefault(model[result.sources[f"rmse_{second}s_m"]], []).append(second)
    if all(seconds_of == [h] for h, seconds_of in at.items()):
        rmse = "RMSE at h s from the model trained for h s"
    else:
        rmse = "RMSE " + "; ".join(
            f"at {seconds_words(seconds_of)} from the {h:g} s model" for h, seconds_of in at.items()
        )
    return (
        f"{len(result.members)} models, one per horizon ({seconds_words(result.horizons_s)}): "
        f"{rmse}; {whole} from the {horizon_s:g} s model{paper}. Constant velocity likewise, on "
        "the same targets."
    )
