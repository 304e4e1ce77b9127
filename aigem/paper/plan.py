"""What `aigem paper` runs: the parts of the report (PARTS), the fits they need (FITS, NEEDS),
each fit's run at each seed (SeedRun), and how this call runs them (PaperCall). Light: no
PyTorch, so that the command checks its options before PyTorch loads.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from aigem.paper.folder import PaperConfig, run_name
from aigem.paper_layout import PAPER_D_MIN_M, build_name
from ngsim_graphs.config import MAX_PARALLEL, MAX_SEED, check_above, check_count

PARTS = ("table", "dmin", "concat", "curves", "regions")
PAPER_FIT = build_name(PAPER_D_MIN_M)  # the paper's model: d_min 25 m, the output concatenation


@dataclass(frozen=True)
class FitPlan:
    """One five-horizon fit of the paper's section: its name, its build's d_min, and whether
    the output MLP sees the previous position."""

    name: str
    d_min_m: float
    concat_position: bool = True

    @property
    def build_name(self) -> str:
        return build_name(self.d_min_m)

    def describe(self) -> str:
        without = " without concatenation" if not self.concat_position else ""
        return f"d_min {self.d_min_m:g} m{without}"


FITS = (
    FitPlan(PAPER_FIT, PAPER_D_MIN_M),
    FitPlan(f"{PAPER_FIT}-no-concat", PAPER_D_MIN_M, concat_position=False),
    FitPlan("dmin-0m", 0.0),
    FitPlan("dmin-50m", 50.0),
)
NEEDS = {  # the fits each part of the report reads
    "table": (PAPER_FIT,),
    "dmin": ("dmin-0m", PAPER_FIT, "dmin-50m"),
    "concat": (PAPER_FIT, f"{PAPER_FIT}-no-concat"),
    "curves": (PAPER_FIT,),
    "regions": (PAPER_FIT,),
}


@dataclass(frozen=True)
class SeedRun:
    """A fit trained at one seed: its own run, runs/`name` (folder.run_name); `several`:
    whether the call trains more than one seed (its words then say which)."""

    plan: FitPlan
    seed: int
    name: str
    several: bool = False

    def describe(self) -> str:
        return self.plan.describe() + (f", seed {self.seed}" if self.several else "")


@dataclass(frozen=True)
class PaperCall:
    """How this call runs the work; none of it is compared with an earlier call's."""

    parts: tuple[str, ...] = PARTS
    device: str = "auto"
    threads: int | None = None  # the model step's CPU threads (a number: bit-reproducible)
    max_hours: float | None = None  # for the training; each run gets its share of what is left
    jobs: int = 1  # the builds' worker processes
    overwrite: bool = False
    seeds: int = 1  # each fit trained at paper.json's seed and the seeds - 1 after it

    def __post_init__(self) -> None:
        check_count("seeds", self.seeds, 1)
        if self.threads is not None:
            check_count("threads", self.threads, 1, MAX_PARALLEL)
        check_count("jobs", self.jobs, 1, MAX_PARALLEL)
        if self.max_hours is not None:
            check_above("max_hours", self.max_hours, 0)


def parse_parts(text: str) -> tuple[str, ...]:
    """'table,dmin' -> ('table', 'dmin'), in PARTS' order; ValueError in one line."""
    given = [part.strip().lower() for part in text.split(",") if part.strip()]
    unknown = [part for part in given if part not in PARTS]
    if unknown or not given:
        what = f"{', '.join(unknown)}: not " if unknown else "none given; "
        raise ValueError(f"{what}a part of the report ({', '.join(PARTS)})")
    return tuple(part for part in PARTS if part in given)


def plan_fits(parts: Sequence[str]) -> tuple[FitPlan, ...]:
    """The fits that `parts` need, in FITS' order (the paper's model first)."""
    names = {name for part in parts for name in NEEDS[part]}
    return tuple(plan for plan in FITS if plan.name in names)


def plan_builds(parts: Sequence[str]) -> tuple[float, ...]:
    """The d_min (m) of each build that `parts` need, ascending."""
    return tuple(sorted({plan.d_min_m for plan in plan_fits(parts)}))


def plan_seeds(config: PaperConfig, call: PaperCall) -> tuple[int, ...]:
    """The seeds of this call: paper.json's seed, the first, and the `call.seeds - 1` after it;
    ValueError where the last is beyond the seeds NumPy and PyTorch take (MAX_SEED)."""
    last = config.seed + call.seeds - 1
    if last > MAX_SEED:
        raise ValueError(
            f"seeds {call.seeds}, seed {config.seed}: the last seed would be {last}, above "
            f"{MAX_SEED} (2**32 - 1)"
        )
    return tuple(range(config.seed, last + 1))


def plan_runs(config: PaperConfig, call: PaperCall) -> tuple[SeedRun, ...]:
    """Each fit the parts need at each seed: seed by seed (the first seed's fits first, in
    FITS' order), so that an interrupted call has finished whole seeds first."""
    several = call.seeds > 1
    return tuple(
        SeedRun(plan, seed, run_name(plan.name, seed, config.seed), several)
        for seed in plan_seeds(config, call)
        for plan in plan_fits(call.parts)
    )
