"""report.md's result sections: Table 1, the d_min and concatenation ablations, the training
curves and front / mid / rear, each report.json's cells (aigem.paper.report_parts) as a Markdown table
with the words that say what its intervals measure. aigem.paper.report_text puts them under the
report's head.

Every AiGem number is shown as its cell (aigem.paper.report_cells.shown): "1.23 [1.18, 1.28]", the
mean over the seeds and its 95 % interval, or with one seed the number and its run's bootstrap
interval over the test samples (Table 1, the ablations), or the number alone. With seeds each
ablation gives its difference to the paper's configuration per horizon and says where it is
beyond the training noise and where within it; with one seed each ablation gives each fit's
AiGem minus constant velocity (the bootstrap's, as Table 1 does) instead: a difference between
two fits cannot be told from the training noise. Constant velocity is one row of a table where
it is alike on every fit's targets. Each heading says SYNTHETIC (PARTLY SYNTHETIC) and
UNFINISHED where the report is so (heading_mark).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from aigem.paper.report_cells import SECONDS, TABLE1_KEYS, Cell, known, noise_sentence, shown

# Why a train curve may lie above the validation one (ModelConfig.dropout is 0.05).
TRAIN_ABOVE_VALIDATION = (
    "The train RMSE can lie above the validation RMSE: it is the mean over the epoch's batches, "
    "with the model's 5 % dropout active and the weights still changing, while validation scores "
    "the epoch's final model with dropout off."
)
# Why the ablations hold no difference between two fits with one seed.
NO_FIT_DIFFERENCE = (
    "With one seed no fit can be told from another beyond the training noise, which the "
    "brackets do not hold: `--seeds 3` or more gives each fit's difference to the paper's "
    "configuration its interval."
)


def _count(value: int | None) -> str:
    return "–" if value is None else f"{value:,}"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _rmse_header(first: str) -> list[str]:
    return [first, *(f"RMSE {s} s (m)" for s in SECONDS)]


def data_mark(document: dict[str, Any]) -> str | None:
    """What the report says of its data: SYNTHETIC, PARTLY SYNTHETIC, or nothing (None)."""
    if document["synthetic"]:
        return "SYNTHETIC"
    return "PARTLY SYNTHETIC" if document["partly_synthetic"] else None


def heading_mark(document: dict[str, Any]) -> str:
    """What a heading says of the whole report: (PARTLY) SYNTHETIC data, UNFINISHED training."""
    marks = [data_mark(document)] + ["UNFINISHED"] * (not document["finished"])
    said = [mark for mark in marks if mark]
    return f" ({', '.join(said)})" if said else ""


def _noise_lines(
    subject: Callable[[str], str], cells: dict[str, list[Cell | None]], kind: str = "seeds"
) -> list[str]:
    """One sentence per difference (noise_sentence; `kind`: which intervals, naming the noise
    they measure), as a list; none without intervals."""
    if not any(known(row) for row in cells.values()):
        return []
    return [f"- {noise_sentence(subject(label), row, kind)}" for label, row in cells.items()] + [""]


def _kind(intervals: dict[str, Any] | None) -> str:
    """The kind of a part's intervals ("seeds" where it has none of its own: the report's)."""
    return "seeds" if intervals is None else intervals["kind"]


def _bootstrap_note(intervals: dict[str, Any], whose: str) -> str:
    """What a part's bootstrap brackets are: `whose` run, resampled how often."""
    return (
        f"- In brackets: {100 * intervals['level']:g} % intervals of {whose} "
        f"({intervals['method']}; {intervals['resamples']:,} resamples of "
        f"{intervals['samples']:,} samples)."
    )


def table1_lines(document: dict[str, Any]) -> list[str]:
    part = document["table1"]
    header = ["model", "ADE (m)", "FDE (m)", *(f"RMSE {s} s (m)" for s in SECONDS), "params (K)"]
    header.append("numbers")
    mark = data_mark(document)
    ours = "this call" + (f", {mark} data" if mark else "")
    rows = []
    for source, table in ((ours, part["ours"]), ("published, NGSIM", part["published"])):
        for name, row in table.items():
            params = row.get("params_k")
            rows.append(
                [
                    name,
                    *(shown(row[k]) for k in TABLE1_KEYS),
                    "–" if params is None else f"{params:g}",
                ]
                + [source]
            )
    notes = [f"- {name}: {note}." for name, note in part["published_notes"].items()]
    against = {"AiGem": part["aigem_minus_constant_velocity_rmse_m"]}
    bootstrap = part.get("intervals")
    if bootstrap is not None:
        notes.append(_bootstrap_note(bootstrap, "this one seed's run"))
    return [
        "## Table 1: AiGem beside constant velocity and the published models"
        + heading_mark(document),
        "",
        *markdown_table(header, rows),
        "",
        "AiGem's RMSE at h s comes from the model trained for h s, its ADE and FDE from the 5 s "
        "model (the paper's protocol); constant velocity is scored on the same targets. Targets "
        "at 1..5 s: " + ", ".join(_count(n) for n in part["targets"]) + ".",
        f"Published rows: {part['published_source']}.",
        *notes,
        "",
        *_difference_table("AiGem minus constant velocity", against),
        *_noise_lines(
            lambda _: "AiGem against constant velocity on the same targets",
            against,
            _kind(bootstrap),
        ),
        "![Table 1 as a figure](figures/table1.png)",
        "",
    ]


def _published_rows(document: dict[str, Any], extra: int = 0) -> list[list[str]]:
    """The published rows beside an ablation or the regions (`extra` empty cells after them)."""
    return [
        [f"{name}, published NGSIM", *map(shown, values), *["–"] * extra]
        for name, values in document["published_rmse_m"].items()
    ]


def _difference_table(first: str, cells: dict[str, list[Cell | None]]) -> list[str]:
    """A table of differences (signed cells), one row per label; none without intervals."""
    if not any(known(row) for row in cells.values()):
        return []
    rows = [[label, *(shown(cell, signed=True) for cell in row)] for label, row in cells.items()]
    return [*markdown_table(_rmse_header(first), rows), ""]


def series_lines(
    document: dict[str, Any],
    key: str,
    title: str,
    first: str,
    named: Callable[[str], str],
    against: Callable[[str], str],
) -> list[str]:
    """An ablation's AiGem rows, constant velocity (once, on the fits' targets), the published
    rows; with one seed each fit's bootstrap intervals and its AiGem minus constant velocity (as
    Table 1), with seeds each fit's difference to the paper's configuration; what each says
    (`named(label)`: a fit in words; `against(label)`: the subject of a fit's difference to the
    paper's configuration)."""
    rows = [[label, *map(shown, values)] for label, values in document[key].items()]
    rows += _constant_velocity_rows(document[f"{key}_constant_velocity"])
    bootstrap = document.get(f"{key}_intervals")
    notes = [document["published_rmse_note"], ""]
    if bootstrap is None:
        differences = document[f"{key}_difference"]
        judged = [
            *_difference_table(f"{first}: minus the paper's", differences),
            *_noise_lines(against, differences),
        ]
    else:
        notes += [_bootstrap_note(bootstrap, "each fit's one run"), "", NO_FIT_DIFFERENCE, ""]
        minus = document[f"{key}_minus_constant_velocity"]
        subject = lambda label: f"{named(label)}: AiGem against constant velocity"  # noqa: E731
        judged = [
            *_difference_table(f"{first}: AiGem minus constant velocity", minus),
            *_noise_lines(subject, minus, "bootstrap"),
        ]
    return [
        f"## {title}{heading_mark(document)}",
        "",
        *markdown_table(_rmse_header(first), rows + _published_rows(document)),
        "",
        *notes,
        *judged,
        f"![{title}](figures/{key}.png)",
        "",
    ]


def _constant_velocity_rows(cells: dict[str, list[Cell | None]]) -> list[list[str]]:
    """Constant velocity's row of an ablation: once where its numbers are alike on every fit's
    targets (constant velocity depends on the targets alone), else one row per fit."""
    shown_rows = {label: [shown(cell) for cell in values] for label, values in cells.items()}
    if len({tuple(row) for row in shown_rows.values()}) == 1:
        return [["constant velocity, same targets", *next(iter(shown_rows.values()))]]
    return [
        [f"{label}: constant velocity, same targets", *row] for label, row in shown_rows.items()
    ]


def _epochs_words(values: Sequence[int | None]) -> str:
    """Each seed's number, once where all agree: "2", "1, 2, 1", "–" for none."""
    words = ["–" if value is None else str(value) for value in values]
    return words[0] if len(set(words)) == 1 else ", ".join(words)


def curves_lines(document: dict[str, Any]) -> list[str]:
    rows = [
        [
            name,
            _epochs_words([len(seed["epoch"]) for seed in curve["seeds"]]),
            _epochs_words(curve["best_epoch"]),
            shown(curve["at_best"]["train_rmse_m"]),
            shown(curve["at_best"]["val_rmse_m"]),
        ]
        for name, curve in document["curves"].items()
    ]
    header = ["model", "epochs", "best epoch", "train RMSE (m)", "validation RMSE (m)"]
    several = len(document["seeds"]) > 1
    return [
        f"## Training curves of the paper's model (d_min 25 m){heading_mark(document)}",
        "",
        *markdown_table(header, rows),
        "",
        "RMSE here is the square root of the logged MSE over the valid future steps; the best "
        "epoch (lowest validation loss) is the model kept"
        + ("; epochs and best epochs are each seed's, the RMSE at each seed's best epoch" * several)
        + ". "
        + TRAIN_ABOVE_VALIDATION,
        "",
        "![Training curves](figures/curves.png)",
        "",
    ]


def regions_lines(document: dict[str, Any]) -> list[str]:
    part = document["regions"]
    y = f"{part['front_y_m']:g}"
    words = {
        "front": f"front (y > {y} m)",
        "mid": f"mid (-{y} m ≤ y ≤ {y} m)",
        "rear": f"rear (y < -{y} m)",
    }
    rows = [
        [words[region], *map(shown, values), _count(part["targets"][region][-1])]
        for region, values in part["rmse_m"].items()
    ]
    rows += [
        [
            f"{words[region]}: constant velocity",
            *map(shown, values),
            _count(part["targets"][region][-1]),
        ]
        for region, values in part["constant_velocity_rmse_m"].items()
    ]
    return [
        f"## Front / mid / rear: RMSE by the actor's present position{heading_mark(document)}",
        "",
        *markdown_table(
            [*_rmse_header("region"), "targets at 5 s"], rows + _published_rows(document, 1)
        ),
        "",
        document["published_rmse_note"],
        "",
        "![RMSE by region](figures/regions.png)",
        "",
    ]
