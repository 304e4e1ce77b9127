"""The cells of `aigem paper`'s report: every number of this call as an interval (report.json
holds aigem.intervals.Interval.as_dict(): {"value", "low", "high"}; None where there is no
number), how report.md shows one, and the words that say whether a difference between two
settings is beyond the noise.

    seed_cell        one number over the seeds: their mean and Student's t 95 % interval
                     (aigem.intervals.seed_interval); with one seed, the number without bounds
    difference_cells one setting's RMSE minus another's, per horizon, paired by seed: each
                     seed's difference, then their mean and interval
    noise_sentence   per horizon, whether that difference's interval excludes 0 (beyond the
                     noise: another set of seeds, or of test samples, would keep its sign) or
                     holds it (within)

A cell of one seed has no bounds; an interval of another kind (a bootstrap over one run's test
samples) fits the same cell and is shown alike. The two kinds measure two noises, which the
words name apart (NOISES): the seeds' intervals the training noise, the bootstrap's the test
set's.
"""

from __future__ import annotations

from collections.abc import Sequence

from aigem.intervals import Interval, seed_interval
from aigem.paper.folder import HORIZONS_S

SECONDS = tuple(round(h) for h in HORIZONS_S)  # 1..5: the keys' rmse_{s}s_m
TABLE1_KEYS = ("ade_m", "fde_m", *(f"rmse_{s}s_m" for s in SECONDS))  # its number columns
Cell = dict[str, float | None]  # Interval.as_dict(): value, low, high (None: no bounds)
LOWER, HIGHER, WITHIN = "lower", "higher", "within"  # a difference's verdict
# What each kind of interval measures, by report.json's intervals "kind": its name in the words.
NOISES = {"seeds": "training noise", "bootstrap": "test-set noise"}
NOISES_SAID = (
    "Two noises are named apart here. The training noise: how much another seed "
    "(initialisation, shuffling, dropout) would change a run's numbers; only runs at several "
    "seeds measure it (`--seeds`). The test-set noise: how much another draw of test samples "
    "would change them; a bootstrap over the test samples measures it."
)


def seed_cell(values: Sequence[float | None]) -> Cell | None:
    """One number of each seed (in its unit) -> their mean and 95 % interval; None where a seed
    has no number (a horizon without targets: the targets do not depend on the seed)."""
    if not values or any(value is None for value in values):
        return None
    return seed_interval([float(value) for value in values if value is not None]).as_dict()


def series_cells(series: Sequence[Sequence[float | None]]) -> list[Cell | None]:
    """Per horizon, seed_cell over the seeds: `series` holds each seed's values at 1..5 s."""
    return [seed_cell(values) for values in zip(*series, strict=True)]


def difference_cells(
    ours: Sequence[Sequence[float | None]], reference: Sequence[Sequence[float | None]]
) -> list[Cell | None]:
    """Per horizon, `ours` minus `reference` (each seed's values at 1..5 s, the seeds in the same
    order): each seed's difference (paired by seed: the seeds' shared noise cancels), then their
    mean and interval (seed_cell). None where either has no value."""
    if len(ours) != len(reference):
        raise ValueError(f"{len(ours)} seeds against {len(reference)}: a paired difference")
    differences = [
        [None if a is None or b is None else a - b for a, b in zip(x, y, strict=True)]
        for x, y in zip(ours, reference, strict=True)
    ]
    return series_cells(differences)


def value_of(cell: Cell | None) -> float | None:
    """The cell's number (the mean over the seeds), None for no cell."""
    return None if cell is None else cell["value"]


def interval_of(cell: Cell | None) -> Interval | None:
    return None if cell is None else Interval(cell["value"], cell["low"], cell["high"])


def shown(cell: Cell | float | None, signed: bool = False) -> str:
    """report.md's cell: "1.23 [1.18, 1.28]" (the number, its 95 % interval), "1.23" without
    bounds (one seed; a published number), "–" without a number; `signed`: "+0.12 [+0.05, ...]"."""
    if cell is None:
        return "–"
    number = (lambda v: f"{v:+.2f}") if signed else (lambda v: f"{v:.2f}")
    if not isinstance(cell, dict):
        return number(cell)
    interval = interval_of(cell)
    if interval is None or not interval.known:
        return number(cell["value"])
    return f"{number(interval.value)} [{number(interval.low)}, {number(interval.high)}]"


def verdict(cell: Cell | None) -> str | None:
    """A difference's verdict: LOWER or HIGHER beyond the noise (its interval excludes 0), WITHIN
    it (the interval holds 0); None without a number or without bounds."""
    interval = interval_of(cell)
    if interval is None or not interval.known:
        return None
    if not interval.excludes(0.0):
        return WITHIN
    return LOWER if interval.value < 0 else HIGHER


def known(cells: Sequence[Cell | None]) -> bool:
    """Whether any cell of `cells` has an interval."""
    return any(verdict(cell) is not None for cell in cells)


def seconds_words(seconds: Sequence[float]) -> str:
    """[1, 2, 5] -> "1, 2 and 5 s"; [2.5] -> "2.5 s"."""
    words = [f"{s:g}" for s in seconds]
    listed = words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"
    return f"{listed} s"


def noise_sentence(subject: str, cells: Sequence[Cell | None], kind: str = "seeds") -> str:
    """In words, per horizon (1..5 s), whether `subject`'s RMSE difference (cells: one per
    horizon) is lower or higher beyond the noise its intervals measure (`kind`: "seeds", the
    training noise; "bootstrap", the test-set noise: NOISES), or within it; "no interval" where
    the cells have no bounds (one seed)."""
    noise = NOISES[kind]
    verdicts = [verdict(cell) for cell in cells]
    if all(v is None for v in verdicts):
        return f"{subject}: no interval (one seed), so no telling this difference from the {noise}."
    said = []
    for which, words in (
        (LOWER, f"lower (better) beyond the {noise}"),
        (HIGHER, f"higher (worse) beyond the {noise}"),
        (WITHIN, f"within the {noise} (the interval holds 0)"),
    ):
        at = [s for s, v in zip(SECONDS, verdicts, strict=True) if v == which]
        if at:
            said.append(f"{words} at {seconds_words(at)}")
    missing = [s for s, v in zip(SECONDS, verdicts, strict=True) if v is None]
    if missing:
        said.append(f"no number at {seconds_words(missing)}")
    return f"{subject}: RMSE {'; '.join(said)}."
