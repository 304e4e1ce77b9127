"""The folder of `aigem paper` (aigem.paper.experiments): whether it is ours, the settings of its work
(paper.json), and what an earlier call left that this one reuses: a finished build of the right
config and inputs, each fit's kept epochs.

paper.json is written first into a new or empty folder and names the work: the inputs (the
trajectory files read, by name, size and sha256: list_inputs), PaperConfig, the builds' config
and the horizons. A folder that holds another program's files is never written into; one of ours
with other settings only with `overwrite`, which discards the runs (only the files a fit writes)
where the training settings make other models (`retrains`) before paper.json is rewritten; more
epochs continue them. A build of another config or other inputs is rebuilt, and the runs
trained on it discarded, by aigem.paper.experiments.

Each fit is trained once per seed (`aigem paper --seeds N`: the seeds paper.json's seed, the
first, to seed + N - 1), each seed its own run: the first seed's in runs/FIT (as a folder of
one seed has always held it), seed S's in runs/FIT-seedS (`run_name`). N is no setting of the
work: a call with more seeds adds the runs of the new ones, one with fewer reports the first N
and leaves the others; another first seed (paper.json's seed) retrains them all.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from functools import cache
from pathlib import Path
from typing import Any

from aigem.paper_layout import PAPER_JSON, REPORT_JSON, REPORT_MD, RUNS, WRITTEN_BY, is_ours
from aigem.runs.records import HORIZONS, LAST, RUN_FILES, STARTED, member_dir
from aigem.runs.run_log import EpochRow, read_metrics
from ngsim_graphs.config import BuildConfig, check_seed
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.integrity import file_sha256
from ngsim_graphs.landing import json_object, some_names
from ngsim_graphs.layout import manifest_path
from ngsim_graphs.partial_files import leftover_partials, write_atomic

HORIZONS_S = (1.0, 2.0, 3.0, 4.0, 5.0)  # the paper's: one model per horizon
PAPER_EPOCHS = 100  # the paper's: "approximately 100 training epochs" gave each best model
RETRAIN = ("seed", "batch_size", "patience_epochs")  # PaperConfig's: other models


@dataclass(frozen=True)
class PaperConfig:
    """What defines the work (paper.json): a later call with other values is refused."""

    epochs: int = PAPER_EPOCHS
    patience_epochs: int | None = None
    seed: int = 0
    batch_size: int = 32

    def __post_init__(self) -> None:
        if self.epochs < 1:
            raise ValueError("epochs must be >= 1")
        if self.batch_size < 1:
            raise ValueError("batch_size must be >= 1")
        if self.patience_epochs is not None and self.patience_epochs < 1:
            raise ValueError("patience_epochs must be >= 1")
        check_seed("seed", self.seed)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def run_name(fit_name: str, seed: int, first_seed: int) -> str:
    """The folder under runs/ of a fit's run at `seed`: the first seed's the fit's own name,
    another's with "-seed{seed}" (dmin-25m, dmin-25m-seed1, dmin-25m-seed2 for seeds 0..2)."""
    return fit_name if seed == first_seed else f"{fit_name}-seed{seed}"


def runs_of(out: Path, fit_names: Sequence[str]) -> list[str]:
    """The names of the runs under out/runs of the fits named `fit_names`, at any seed: the
    fit's name, or it followed by "-seed" and an integer (run_name), sorted."""
    folder = out / RUNS
    found = [path.name for path in folder.iterdir()] if folder.is_dir() else []
    return sorted(name for name in found if any(_of_fit(name, fit) for fit in fit_names))


def _of_fit(name: str, fit_name: str) -> bool:
    pattern = rf"{re.escape(fit_name)}-seed-?(0|[1-9]\d*)"
    return name == fit_name or re.fullmatch(pattern, name) is not None


def list_inputs(raw_paths: Sequence[Path]) -> list[dict[str, Any]]:
    """The trajectory files a build reads under `raw_paths` (the source's choice: a readme or
    another file that is not a recording is skipped), each by name, size and sha256, in that
    order: what a later call and a build's manifest are compared by. A moved folder holds the
    same inputs; a file changed, added or taken away makes other inputs."""
    from ngsim_graphs.sources.archives import archives_in
    from ngsim_graphs.sources.registry import choose_source

    for path in raw_paths:
        refuse_build_as_input(Path(path))
    packed = [archive for path in raw_paths for archive in archives_in(Path(path))]
    if packed:  # its digest is not its members': a build of them could not be told reusable
        raise NgsimInputError(
            packed[0], "aigem paper reads no compressed file: unpack it first (build reads it)"
        )
    _, files, _ = choose_source(list(raw_paths))
    found = [_identity(path) for path in files]
    return sorted(found, key=lambda f: (f["name"], f["sha256"]))


def refuse_build_as_input(path: Path) -> None:
    """Refuse an ngsim-graphs build given as a raw input: `aigem paper` makes its own three
    builds from the trajectory files (the build's manifest names those it was made from)."""
    manifest = json_object(manifest_path(path)) if path.is_dir() else None
    if manifest is None:
        return
    made_from = sorted({str(f["path"]) for f in manifest.get("inputs") or [] if "path" in f})
    said = f" (this one was made from {', '.join(made_from)})" if made_from else ""
    raise NgsimInputError(
        path,
        "is an ngsim-graphs build, not raw trajectory files: aigem paper makes its three builds "
        f"itself from the files a build is made of{said}; give those files or their folder",
    )


def _identity(path: Path) -> dict[str, Any]:
    stat = path.stat()
    digest = _sha256(str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    return {"name": path.name, "size_bytes": stat.st_size, "sha256": digest}


@cache
def _sha256(path: str, size_bytes: int, mtime_ns: int) -> str:
    """A file's sha256, hashed once per process while its size and mtime stay (the command
    checks the folder before PyTorch loads, then again as it starts: 1.5 GB is hashed once)."""
    return file_sha256(Path(path))


def _contents(inputs: Sequence[dict[str, Any]] | None) -> list[tuple[str, str]]:
    """(name, sha256) of each input, sorted: two lists of inputs are the same inputs when these
    are equal (an entry without them, of an older paper.json, is another input)."""
    return sorted(
        (str(f.get("name") or Path(str(f.get("path"))).name), str(f.get("sha256")))
        for f in inputs or []
    )


def _named(old: list[tuple[str, str]], new: list[tuple[str, str]]) -> str:
    """The names of the inputs that differ between two _contents, for a one-line message."""
    return some_names(sorted({name for name, _ in set(old) ^ set(new)}))


def paper_document(raw_paths: Sequence[Path], config: PaperConfig) -> dict[str, Any]:
    """paper.json: the marker that the folder is ours, and what defines its work."""
    document = {
        "written_by": WRITTEN_BY,
        "inputs": list_inputs(raw_paths),
        "config": config.to_dict(),
        "build_config": BuildConfig().to_dict(),  # but d_min_m, set per build
        "horizons_s": list(HORIZONS_S),
    }
    return json.loads(json.dumps(document))  # as a later call reads it back: lists, not tuples


def differences(before: dict[str, Any], now: dict[str, Any]) -> list[str]:
    """What differs between two paper.json documents, in words ("epochs 2 -> 100")."""
    said = []
    old, new = _contents(before.get("inputs")), _contents(now["inputs"])
    if old != new:
        said.append(f"inputs ({_named(old, new)})")
    for key in ("config", "build_config"):
        old, new = before.get(key) or {}, now[key]
        said += [f"{k} {old.get(k)} -> {new[k]}" for k in new if old.get(k) != new[k]]
    if before.get("horizons_s") != now["horizons_s"]:
        said.append("horizons")
    return said


def check_folder(out: Path, document: dict[str, Any], overwrite: bool) -> None:
    """Refuse, writing nothing, an `out` that claim_folder must not take: a file, a folder that
    is not empty and not ours, or ours with other settings (without `overwrite`), naming them."""
    if out.exists() and not out.is_dir():
        raise NgsimOutputError(out, "is a file, not a folder; choose another --out")
    before = json_object(out / PAPER_JSON)
    if not is_ours(before):
        if out.is_dir() and any(out.iterdir()):
            raise NgsimOutputError(
                out,
                f"folder is not empty and was not written by `aigem paper` (no {PAPER_JSON} of "
                "its own); choose a new or empty --out",
            )
        return
    changed = differences(before, document)
    if changed and not overwrite:
        raise NgsimOutputError(
            out,
            f"holds `aigem paper`'s work with other settings ({'; '.join(changed)}); run it "
            "with those to continue, or add --overwrite to start over with these",
        )


def retrains(before: dict[str, Any], now: dict[str, Any]) -> bool:
    """Whether `now`'s training settings make other models than `before`'s: another seed, batch
    size or patience, or fewer epochs. More epochs continue the runs (the paper's constant
    learning rate does not depend on them), as the same command would after a time limit."""
    old, new = before.get("config") or {}, now["config"]
    if any(old.get(key) != new[key] for key in RETRAIN):
        return True
    return not isinstance(old.get("epochs"), int) or old["epochs"] > new["epochs"]


def claim_folder(
    out: Path, document: dict[str, Any], overwrite: bool, run_names: Sequence[str]
) -> None:
    """Make `out` ours for `document`'s work (check_folder first): new or empty, paper.json
    written first; ours with the same settings, as it is; ours with others (`overwrite`): the
    runs named `run_names` (every seed's: runs_of) discarded where the models would differ
    (`retrains`), then paper.json rewritten. An earlier call's report.json and report.md go:
    none is there until this call has finished."""
    check_folder(out, document, overwrite)
    marker = out / PAPER_JSON
    before = json_object(marker)
    if not is_ours(before):
        out.mkdir(parents=True, exist_ok=True)
        write_atomic(marker, _json_bytes(document))
        return
    for name in (REPORT_JSON, REPORT_MD):
        (out / name).unlink(missing_ok=True)
    if not differences(before, document):
        return
    if retrains(before, document):
        for name in run_names:
            discard_run(out / RUNS / name)
    write_atomic(marker, _json_bytes(document))


def _json_bytes(document: dict[str, Any]) -> bytes:
    return (json.dumps(document, indent=2) + "\n").encode()


def discard_run(run_dir: Path) -> None:
    """Remove a multi-horizon run's files (only the names a fit writes) and the folders they
    leave empty; anything else stays, and a later fit refuses the folder naming it."""
    if not run_dir.is_dir() or run_dir.is_symlink():
        return
    for horizon_s in HORIZONS_S:
        member = member_dir(run_dir, horizon_s)
        if member.is_dir() and not member.is_symlink():
            _remove_names(member, (*RUN_FILES, STARTED))
    _remove_names(run_dir, (HORIZONS, STARTED))


def _remove_names(folder: Path, names: Sequence[str]) -> None:
    for path in leftover_partials(folder, names):
        path.unlink(missing_ok=True)
    for name in names:
        path = folder / name
        if path.is_file() or path.is_symlink():
            path.unlink()
    if not any(folder.iterdir()):
        folder.rmdir()


def build_config(d_min_m: float) -> BuildConfig:
    return BuildConfig(d_min_m=d_min_m)


def _changed(ours: dict[str, Any], theirs: dict[str, Any]) -> str:
    """The settings of `ours` that `theirs` holds otherwise: "name THEIRS -> OURS; ..."."""
    return "; ".join(f"{k} {theirs.get(k)} -> {v}" for k, v in ours.items() if theirs.get(k) != v)


def build_state(build_dir: Path, config: BuildConfig, inputs: list[dict[str, Any]]) -> str | None:
    """ "" for a finished build in `build_dir` to reuse (of `config`, read from exactly `inputs`:
    list_inputs's, compared by name and sha256); None where there is none (no manifest); else
    why it cannot be reused."""
    from ngsim_graphs.build import open_build
    from ngsim_graphs.sources.registry import SOURCES

    if not manifest_path(build_dir).is_file():
        return None
    manifest = open_build(build_dir).manifest
    if manifest.config != config:
        changed = _changed(config.to_dict(), manifest.config.to_dict())
        return f"is a build of another config ({changed})"
    source = SOURCES.get(manifest.dataset)
    if manifest.limits is not None and source is not None and manifest.limits != source.limits:
        changed = _changed(asdict(source.limits), asdict(manifest.limits))
        return f"holds the rows to other physical limits than its source's ({changed})"
    built = sorted((Path(f.path).name, f.sha256) for f in manifest.inputs)
    now = _contents(inputs)
    return f"was built from other inputs ({_named(built, now)})" if built != now else ""


def partly_synthetic(build_dirs: Sequence[Path]) -> bool:
    """Whether a build in `build_dirs` mixes synth's files with others (its manifest's record)."""
    from ngsim_graphs.build import open_build
    from ngsim_graphs.synth.marker import synthetic_build, synthetic_inputs_of

    manifests = [open_build(build_dir).manifest for build_dir in build_dirs]
    return any(synthetic_inputs_of(m) and not synthetic_build(m) for m in manifests)


def _member_progress(member: Path, config: PaperConfig) -> tuple[int, list[EpochRow], str]:
    """(epochs kept in its last.pt, their metrics rows, why it trains no more: course.stop_reason,
    UNFINISHED while it has epochs left)."""
    from aigem.runs.checkpoints import check_log, epochs_kept  # PyTorch, only when a run is read
    from aigem.runs.course import stop_reason

    kept = epochs_kept(member) if (member / LAST).is_file() else 0
    if kept:
        check_log(member, kept)
    rows = [row for row in read_metrics(member) if row.epoch <= kept] if kept else []
    return kept, rows, stop_reason(kept, config.epochs, rows, config.patience_epochs)


def epochs_left(run_dir: Path, config: PaperConfig) -> int:
    """Epochs a five-horizon fit still runs (0: every model is done): from the epoch of its
    least advanced model still training (early stopping may end it sooner)."""
    from aigem.runs.course import UNFINISHED

    states = [_member_progress(member_dir(run_dir, h), config) for h in HORIZONS_S]
    training = [kept for kept, _, reason in states if reason == UNFINISHED]
    return config.epochs - min(training) if training else 0


def fit_record(run_dir: Path, config: PaperConfig) -> dict[str, dict[str, Any]]:
    """Each model's course, from its kept epochs: epochs done, best epoch, why it stopped (a
    model with epochs left stopped at the time limit)."""
    from aigem.runs.course import UNFINISHED

    record = {}
    for horizon_s in HORIZONS_S:
        member = member_dir(run_dir, horizon_s)
        kept, rows, reason = _member_progress(member, config)
        stopped = "time limit" if reason == UNFINISHED else reason
        best = rows[-1].best_epoch if rows else None
        record[member.name] = {"epochs_done": kept, "best_epoch": best, "stopped": stopped}
    return record
