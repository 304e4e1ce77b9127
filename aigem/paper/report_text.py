"""report.md of `aigem paper`: report.json's document (aigem.paper.report) as Markdown. This module
writes its head (the data, the inputs, the training settings, what the intervals are), the runs
(each model's "trained N of M" epochs) and the time taken, around the result sections of
aigem.paper.report_tables (Table 1, the ablations, the curves, front / mid / rear).

The words name the two noises apart (report_cells.NOISES): the seeds' intervals measure the
training noise, the bootstrap's the test-set noise; with one seed the report says so once, at
its top (ONE_SEED). The head says the epochs beside the paper's.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from aigem.paper.folder import PAPER_EPOCHS
from aigem.paper.report_cells import NOISES_SAID
from aigem.paper.report_tables import (
    curves_lines,
    data_mark,
    heading_mark,
    markdown_table,
    regions_lines,
    series_lines,
    table1_lines,
)

UNFINISHED = "UNFINISHED: training stopped by --max-hours; run the same command again to continue"
TIME_HEADING = "## Time taken"  # report.md's last section: the only one that differs between calls
ONE_SEED = (
    "One seed: no difference between two settings (an ablation, AiGem against constant "
    "velocity) can be told from the training noise; `--seeds 3` or more gives each AiGem number "
    "and each difference its 95 % interval over the seeds. The brackets of this report hold the "
    "test-set noise alone (a bootstrap over the test samples of each fit's one run)."
)


def _counted(count: int, noun: str) -> str:
    return f"{count:,} {noun}{'' if count == 1 else 's'}"


def seeds_words(seeds: Sequence[int]) -> str:
    """ "seed 0" or "seeds 0, 1, 2"."""
    return f"seed{'s' * (len(seeds) > 1)} {', '.join(str(s) for s in seeds)}"


def intervals_lines(document: dict[str, Any]) -> list[str]:
    """What the intervals are, once at the top (ONE_SEED where there are none)."""
    kind = document.get("intervals")
    if kind is None:
        return [NOISES_SAID, "", ONE_SEED, ""]
    return [
        NOISES_SAID,
        "",
        f"Each fit was trained {len(document['seeds'])} times, at {seeds_words(document['seeds'])}"
        f" (a run each). Every AiGem number is the mean over the seeds and, in brackets, its "
        f"{100 * kind['level']:g} % interval ({kind['method']}): the training noise. A difference "
        "between two settings is taken seed by seed before its mean and interval; it is beyond "
        "the training noise where its interval excludes 0, within it where the interval holds 0. "
        "Constant velocity does not depend on the seed: its numbers have no interval.",
        "",
    ]


def _courses(models: dict[str, dict[str, Any]], epochs: int) -> str:
    """Each model's 'trained N of M epochs' and best epoch, why they stopped (once where alike),
    and where the time limit stopped one, how to continue."""
    stops = {m["stopped"] for m in models.values()}
    each = "; ".join(
        f"{name}: trained {m['epochs_done']} of {epochs} (best {m['best_epoch']}"
        + ("" if len(stops) == 1 else f", {m['stopped']}")
        + ")"
        for name, m in models.items()
    )
    line = f"{each}; stopped by {next(iter(stops))}" if len(stops) == 1 else each
    if "time limit" in stops:
        line += "; UNFINISHED: the same `aigem paper` command continues it"
    return line


def _fits_lines(document: dict[str, Any]) -> list[str]:
    """One row per run (a fit at one seed); the seed's column only where there are several."""
    several = len(document["seeds"]) > 1
    rows = [
        [
            run["run"],
            *([str(run["seed"])] * several),
            f"{fit['d_min_m']:g}",
            "yes" if fit["concat_position"] else "no",
            f"{fit['test_samples']:,}",
            _courses(run["models"], document["settings"]["epochs"]),
        ]
        for fit in document["fits"].values()
        for run in fit["runs"]
    ]
    header = ["run", *(["seed"] * several), "d_min (m)", "concatenation", "test samples"]
    return ["## Runs", "", *markdown_table([*header, "epochs of each model"], rows), ""]


def _head_lines(document: dict[str, Any]) -> list[str]:
    """The title, which data, the inputs and the training settings, what the intervals are."""
    settings = document["settings"]
    patience = settings["patience_epochs"]
    size = sum(f["size_bytes"] for f in settings["inputs"])
    lines = [
        f"# AiGem: the paper's experiments{heading_mark(document)}",
        "",
        (
            f"**{data_mark(document)}**: every number of this call comes from "
            f"{document['data']}; only the rows marked published are NGSIM results."
            if data_mark(document)
            else f"Every number of this call comes from {document['data']}."
        ),
        "",
        f"Inputs: {_counted(len(settings['inputs']), 'file')}, {size:,} bytes. Training: up to "
        f"{_counted(settings['epochs'], 'epoch')} per model ({_paper_epochs(settings['epochs'])}"
        f"), batch {settings['batch_size']}, "
        f"{seeds_words(document['seeds'])}, patience {'none' if patience is None else patience}."
        f" Scored on the {document['split']} split.",
        "",
        *intervals_lines(document),
    ]
    if not document["finished"]:
        fits = ", ".join(document["unfinished_fits"])
        lines[2:2] = [f"**{UNFINISHED}** (unfinished fits: {fits}).", ""]
    return lines


def _paper_epochs(epochs: int) -> str:
    """This call's epochs beside the paper's."""
    if epochs == PAPER_EPOCHS:
        return "the paper's"
    return f"the paper trains {PAPER_EPOCHS}; this call {epochs}"


def report_markdown(document: dict[str, Any], timings: dict[str, float]) -> str:
    """report.md: the report's tables, its figures, and the time each stage took (last)."""
    lines = _head_lines(document)
    if "table1" in document:
        lines += table1_lines(document)
    if "dmin" in document:
        named = lambda d: f"d_min {d} m"  # noqa: E731
        against = lambda d: f"d_min {d} m against the paper's 25 m"  # noqa: E731
        lines += series_lines(document, "dmin", "d_min ablation", "d_min (m)", named, against)
    if "concat" in document:
        title = "Output concatenation ablation (d_min 25 m)"
        first = "previous position at the MLP"
        named = lambda label: f"{label} the concatenation"  # noqa: E731
        against = lambda _: "without the concatenation against with it (the paper's)"  # noqa: E731
        lines += series_lines(document, "concat", title, first, named, against)
    if "curves" in document:
        lines += curves_lines(document)
    if "regions" in document:
        lines += regions_lines(document)
    lines += _fits_lines(document)
    lines += [TIME_HEADING, "", *(f"- {stage}: {s:,.1f} s" for stage, s in timings.items()), ""]
    return "\n".join(lines)
