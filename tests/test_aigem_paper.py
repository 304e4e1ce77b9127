"""`aigem paper`: the plan of each --only, the folder (ours or not, its settings), and the whole
command on a tiny input, uninterrupted and killed half-way then run again: the same report."""

from __future__ import annotations

import gzip
import hashlib
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from conftest import straight_track, write_txt
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from timed_runs import LINGER_S, TimedRun, aigem, run_timed

from aigem.paper.experiments import _evaluate, run_paper
from aigem.paper.folder import (
    PaperConfig,
    build_state,
    claim_folder,
    differences,
    discard_run,
    list_inputs,
    paper_document,
    runs_of,
)
from aigem.paper.plan import (
    FITS,
    PARTS,
    PaperCall,
    SeedRun,
    parse_parts,
    plan_builds,
    plan_fits,
    plan_runs,
)
from aigem.paper.report_text import UNFINISHED
from aigem.paper.training import Meter, fit_share_s, work_units
from aigem.paper_layout import PAPER_JSON, PAPER_LOG, REPORT_JSON
from aigem.runs.checkpoints import epochs_kept
from aigem.runs.records import HORIZONS, LAST, METRICS, STARTED, STARTED_LINE
from ngsim_cli.aigem import app
from ngsim_graphs.build import open_build
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.integrity import settings_sha256
from ngsim_graphs.layout import write_manifest_json
from ngsim_graphs.lock import output_lock
from ngsim_graphs.synth.formats import write_synthetic


@pytest.mark.parametrize(
    ("only", "fits", "builds"),
    [
        ("table", ["dmin-25m"], [25.0]),
        ("curves,regions", ["dmin-25m"], [25.0]),
        ("concat", ["dmin-25m", "dmin-25m-no-concat"], [25.0]),
        ("dmin", ["dmin-25m", "dmin-0m", "dmin-50m"], [0.0, 25.0, 50.0]),
        (
            ",".join(PARTS),
            ["dmin-25m", "dmin-25m-no-concat", "dmin-0m", "dmin-50m"],
            [0.0, 25.0, 50.0],
        ),
    ],
)
def test_each_part_selects_the_builds_and_fits_it_needs(
    only: str, fits: list[str], builds: list[float]
) -> None:
    parts = parse_parts(only)
    assert [plan.name for plan in plan_fits(parts)] == fits
    assert list(plan_builds(parts)) == builds


def test_the_fits_are_the_papers_settings() -> None:
    plans = {plan.name: plan for plan in plan_fits(PARTS)}
    assert (plans["dmin-25m"].d_min_m, plans["dmin-25m"].concat_position) == (25.0, True)
    assert not plans["dmin-25m-no-concat"].concat_position
    assert plans["dmin-0m"].build_name == "dmin-0m" and plans["dmin-50m"].d_min_m == 50.0


def test_each_fit_gets_an_equal_share_of_the_time_left() -> None:
    assert fit_share_s(math.inf, 4) == math.inf  # no --max-hours
    assert fit_share_s(3600.0, 4) == 900.0  # an hour left, four fits to train
    assert fit_share_s(600.0, 1) == 600.0
    assert fit_share_s(-5.0, 2) < 0  # the time is out: the fit does not start


def test_parts_are_kept_in_the_reports_order_and_unknown_ones_refused() -> None:
    assert parse_parts(" Regions,table ") == ("table", "regions")
    with pytest.raises(ValueError, match="tabel: not a part of the report"):
        parse_parts("tabel,dmin")
    with pytest.raises(ValueError, match="none given"):
        parse_parts(",")


RUN_NAMES = [plan.name for plan in FITS]


@pytest.fixture
def raw(tmp_path: Path) -> Path:
    """A folder of one NGSIM file, a.txt (three rows), and a readme that is not an input."""
    folder = tmp_path / "raw"
    write_txt(folder / "a.txt", straight_track(1, range(3)))
    (folder / "README.md").write_text("not a recording")
    return folder


def sha256_of(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_new_folder_gets_paper_json_first_and_the_same_settings_continue(
    tmp_path: Path, raw: Path
) -> None:
    out = tmp_path / "out"
    document = paper_document([raw], PaperConfig(epochs=2))
    claim_folder(out, document, overwrite=False, run_names=RUN_NAMES)
    on_disk = json.loads((out / PAPER_JSON).read_text())
    assert on_disk["config"]["epochs"] == 2 and on_disk["written_by"] == "aigem paper"
    a = raw / "a.txt"  # the readme is no input
    size, digest = a.stat().st_size, sha256_of(a)
    assert on_disk["inputs"] == [{"name": "a.txt", "size_bytes": size, "sha256": digest}]
    (out / REPORT_JSON).write_text("{}")
    claim_folder(
        out, paper_document([raw], PaperConfig(epochs=2)), overwrite=False, run_names=RUN_NAMES
    )
    assert not (out / REPORT_JSON).exists()  # none until this call has finished


def test_other_settings_are_refused_naming_them_and_the_earlier_report_stays(
    tmp_path: Path, raw: Path
) -> None:
    out = tmp_path / "out"
    claim_folder(
        out, paper_document([raw], PaperConfig(epochs=2)), overwrite=False, run_names=RUN_NAMES
    )
    (out / REPORT_JSON).write_text("{}")
    write_txt(raw / "a.txt", straight_track(1, range(4)))
    later = paper_document([raw], PaperConfig(epochs=3, seed=1))
    with pytest.raises(NgsimOutputError) as caught:
        claim_folder(out, later, overwrite=False, run_names=RUN_NAMES)
    message = str(caught.value)
    assert "epochs 2 -> 3" in message and "seed 0 -> 1" in message and "a.txt" in message
    assert "--overwrite" in message and "\n" not in message
    assert (out / REPORT_JSON).exists()
    assert differences(json.loads((out / PAPER_JSON).read_text()), later) == [
        "inputs (a.txt)",
        "epochs 2 -> 3",
        "seed 0 -> 1",
    ]


def fake_run(run_dir: Path) -> None:
    """The names a five-horizon fit writes (their content does not matter here)."""
    run_dir.mkdir(parents=True)
    (run_dir / HORIZONS).write_text("{}")
    for s in range(1, 6):
        member = run_dir / f"h{s}s"
        member.mkdir()
        for name in (LAST, METRICS, ".last.pt.partial-0123456789abcdef"):
            (member / name).write_text("x")
        (member / STARTED).write_bytes(STARTED_LINE)


def test_overwrite_discards_the_runs_files_and_nothing_else(tmp_path: Path, raw: Path) -> None:
    out = tmp_path / "out"
    claim_folder(out, paper_document([raw], PaperConfig(epochs=2)), False, RUN_NAMES)
    for name in ("dmin-25m", "dmin-0m", "dmin-7m"):  # dmin-7m: not a run of aigem paper
        fake_run(out / "runs" / name)
    (out / "runs" / "dmin-0m" / "h3s" / "notes.txt").write_text("a user's")
    claim_folder(out, paper_document([raw], PaperConfig(epochs=2, seed=1)), True, RUN_NAMES)
    assert not (out / "runs" / "dmin-25m").exists()
    left = sorted(p.relative_to(out).as_posix() for p in (out / "runs" / "dmin-0m").rglob("*"))
    assert left == ["runs/dmin-0m/h3s", "runs/dmin-0m/h3s/notes.txt"]
    assert (
        len(list((out / "runs" / "dmin-7m").rglob("*"))) == 26
    )  # 5 members of 4 files, horizons.json
    assert json.loads((out / PAPER_JSON).read_text())["config"]["seed"] == 1
    discard_run(out / "runs" / "missing")  # nothing there: nothing to do


def test_each_seed_is_a_run_of_its_own_the_first_seeds_named_as_before(
    tmp_path: Path, raw: Path
) -> None:
    """--seeds 3 from --seed 4: each fit at seeds 4, 5, 6, seed by seed; the first seed's run
    is the fit's own name (a folder of one seed holds it there); runs_of finds every seed's."""
    runs = plan_runs(PaperConfig(seed=4), PaperCall(parts=("concat",), seeds=3))
    assert [(run.name, run.seed) for run in runs] == [
        ("dmin-25m", 4),
        ("dmin-25m-no-concat", 4),
        ("dmin-25m-seed5", 5),
        ("dmin-25m-no-concat-seed5", 5),
        ("dmin-25m-seed6", 6),
        ("dmin-25m-no-concat-seed6", 6),
    ]
    assert runs[2].describe() == "d_min 25 m, seed 5"
    assert plan_runs(PaperConfig(), PaperCall(parts=("table",)))[0].describe() == "d_min 25 m"
    with pytest.raises(ValueError, match="^seeds must be >= 1$"):
        PaperCall(seeds=0)
    out = tmp_path / "out"
    claim_folder(out, paper_document([raw], PaperConfig(epochs=2)), False, RUN_NAMES)
    for name in ("dmin-25m", "dmin-25m-seed1", "dmin-0m-seed-3", "dmin-25m-seedling"):
        fake_run(out / "runs" / name)
    found = runs_of(out, RUN_NAMES)
    assert found == ["dmin-0m-seed-3", "dmin-25m", "dmin-25m-seed1"]  # not dmin-25m-seedling
    claim_folder(out, paper_document([raw], PaperConfig(epochs=2, seed=1)), True, found)
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["dmin-25m-seedling"]


@pytest.mark.parametrize(
    ("later", "kept"),
    [
        (PaperConfig(epochs=3), True),  # more epochs continue the runs
        (PaperConfig(epochs=1), False),  # fewer: a model may have trained past them
        (PaperConfig(epochs=2, batch_size=8), False),
        (PaperConfig(epochs=2, patience_epochs=4), False),
    ],
)
def test_overwrite_keeps_the_runs_unless_the_models_would_differ(
    tmp_path: Path, raw: Path, later: PaperConfig, kept: bool
) -> None:
    out = tmp_path / "out"
    claim_folder(out, paper_document([raw], PaperConfig(epochs=2)), False, RUN_NAMES)
    fake_run(out / "runs" / "dmin-25m")
    claim_folder(out, paper_document([raw], later), True, RUN_NAMES)
    assert (out / "runs" / "dmin-25m" / "h1s" / LAST).exists() == kept
    assert json.loads((out / PAPER_JSON).read_text())["config"] == later.to_dict()


def test_a_folder_not_of_aigem_paper_is_refused_unless_empty(tmp_path: Path, raw: Path) -> None:
    document = paper_document([raw], PaperConfig())
    (tmp_path / "empty").mkdir()
    claim_folder(tmp_path / "empty", document, overwrite=False, run_names=RUN_NAMES)
    assert (tmp_path / "empty" / PAPER_JSON).is_file()
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "thesis.tex").write_text("mine")
    for overwrite in (False, True):
        with pytest.raises(NgsimOutputError, match="not written by `aigem paper`"):
            claim_folder(tmp_path / "theirs", document, overwrite, RUN_NAMES)
    assert sorted(p.name for p in (tmp_path / "theirs").iterdir()) == ["thesis.tex"]


def test_the_command_refuses_a_foreign_folder_and_a_bad_part_in_one_line(
    tmp_path: Path, raw: Path
) -> None:
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "x").write_text("")
    runner = CliRunner()
    result = runner.invoke(app, ["paper", str(raw), "--out", str(tmp_path / "theirs")])
    assert result.exit_code == 1, result.output
    assert result.output.count("\n") == 1 and "not written by `aigem paper`" in result.output
    result = runner.invoke(app, ["paper", str(raw), "--out", str(tmp_path / "o"), "--only", "x"])
    assert result.exit_code == 2 and "--only x: x: not a part of the report" in result.output
    assert not (tmp_path / "o").exists()


def test_the_command_refuses_a_compressed_input_in_one_line(tmp_path: Path, raw: Path) -> None:
    """A zip's digest is not its members': the paper refuses it (build reads it) before any
    folder is made."""
    packed = tmp_path / "packed"
    shutil.copytree(raw, packed)
    a = packed / "a.txt"
    a.with_name("a.txt.gz").write_bytes(gzip.compress(a.read_bytes()))
    a.unlink()
    result = CliRunner().invoke(app, ["paper", str(packed), "--out", str(tmp_path / "o")])
    assert result.exit_code == 1, result.output
    assert result.output.count("\n") == 1
    assert f"{packed / 'a.txt.gz'}: aigem paper reads no compressed file" in result.output
    assert not (tmp_path / "o").exists()


def test_a_build_is_reused_only_with_its_config_and_inputs(
    tiny_build: Path, tmp_path: Path
) -> None:
    manifest = open_build(tiny_build).manifest
    (built_from,) = {Path(f.path).parent for f in manifest.inputs}
    raw = shutil.copytree(built_from, tmp_path / "moved")  # another folder, the same files
    (raw / "README.md").write_text("not a recording")  # skipped by the source: no input
    assert build_state(tiny_build, manifest.config, list_inputs([raw])) == ""  # reuse
    other = build_state(tiny_build, BuildConfig(d_sense_m=12.0, d_min_m=25.0), list_inputs([raw]))
    assert other == "is a build of another config (d_min_m 6.0 -> 25.0)"
    assert build_state(tmp_path, manifest.config, list_inputs([raw])) is None  # no build there

    (recording,) = [p for p in raw.iterdir() if p.suffix == ".txt"]
    added = write_txt(raw / "b.txt", straight_track(1, range(3)))
    stale = build_state(tiny_build, manifest.config, list_inputs([raw]))
    assert stale == "was built from other inputs (b.txt)"
    added.unlink()
    text = recording.read_bytes()
    at = text.index(b"1", len(text) // 2)  # a digit changed: the same size, other content
    recording.write_bytes(text[:at] + b"2" + text[at + 1 :])
    stale = build_state(tiny_build, manifest.config, list_inputs([raw]))
    assert stale == f"was built from other inputs ({recording.name})"


def test_a_build_made_before_the_limits_were_the_sources_is_reused(
    tiny_build: Path, tmp_path: Path
) -> None:
    """Its manifest held the limits in its config (that older form, made here of today's by
    moving them back): the same config, limits and config hash, so the paper reuses it."""
    older = Path(shutil.copytree(tiny_build, tmp_path / "older"))
    values = json.loads((older / "manifest.json").read_text())
    values["config"]["limits"] = values.pop("limits")
    write_manifest_json(older, values)  # sealed anew, as the older code sealed it
    manifest, today = open_build(older).manifest, open_build(tiny_build).manifest
    assert (manifest.config_hash, manifest.config, manifest.limits) == (
        today.config_hash, today.config, today.limits
    )  # fmt: skip
    (built_from,) = {Path(f.path).parent for f in manifest.inputs}
    assert build_state(older, manifest.config, list_inputs([built_from])) == ""


def test_a_moved_folder_holds_the_same_inputs_and_a_changed_file_others(
    tmp_path: Path, raw: Path
) -> None:
    before = paper_document([raw], PaperConfig())
    moved = raw.rename(tmp_path / "elsewhere")
    assert differences(before, paper_document([moved], PaperConfig())) == []
    a = moved / "a.txt"
    a.write_bytes(a.read_bytes().replace(b"100", b"200"))  # the same size
    assert differences(before, paper_document([moved], PaperConfig())) == ["inputs (a.txt)"]
    older = {**before, "inputs": [{"path": "/old/a.txt", "size_bytes": 4}]}  # no sha256
    assert differences(older, before) == ["inputs (a.txt)"]


def test_a_refused_call_leaves_the_earlier_report_and_a_second_call_at_once_is_refused(
    tiny_build: Path, tmp_path: Path
) -> None:
    (raw,) = {Path(f.path).parent for f in open_build(tiny_build).manifest.inputs}
    out, config = tmp_path / "out", PaperConfig(epochs=1)
    claim_folder(out, paper_document([raw], config), False, RUN_NAMES)
    (out / REPORT_JSON).write_text("{}")  # an earlier call's
    shutil.copytree(tiny_build, out / "builds" / "dmin-25m")  # replaced by hand: d_min 6 m
    call = PaperCall(parts=("table",))
    with pytest.raises(NgsimOutputError, match="is a build of another config .* --overwrite"):
        run_paper([raw], out, config, call)
    assert (out / REPORT_JSON).read_text() == "{}"
    with output_lock(out), pytest.raises(NgsimOutputError, match="another process is writing"):
        run_paper([raw], out, config, call)
    assert (out / REPORT_JSON).read_text() == "{}"


def test_an_evaluation_fills_its_share_of_the_bar_one_unit_a_batch(
    tiny_build: Path, tiny_horizons_run: Path, tmp_path: Path
) -> None:
    """The bar counts a fit's evaluation as one pass over the test split (its models stacked),
    and the evaluation moves it one unit a batch, to its share and no further."""
    plan = FITS[0]
    run = SeedRun(plan, 0, plan.name)
    for folder, name, target in (
        ("runs", plan.name, tiny_horizons_run),
        ("builds", plan.build_name, tiny_build),
    ):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / name).symlink_to(target)
    units = work_units(tmp_path, [run], [], PaperConfig())
    test_samples = open_build(tiny_build).manifest.splits["test"]
    assert units == math.ceil(test_samples / 64)
    shown: list[tuple[int, int]] = []
    meter = Meter(lambda _what, done, total: shown.append((done, total)), units)
    _evaluate(run, tmp_path, "cpu", meter)
    assert shown == [(done, units) for done in range(1, units + 1)] and meter.offset == units


# ------------------------------------------------------------------------------------------------
# The whole command: uninterrupted; stopped by --max-hours and run again; killed and run again

FIGURES = ["concat.png", "curves.png", "dmin.png", "regions.png", "table1.png"]


@pytest.fixture(scope="module")
def tiny_raw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One recording of 15 s: 87 train samples (two batches of 64, so that a fit that --max-hours
    stops after its first batch stops inside its epoch), 14 val and 10 test samples."""
    folder = tmp_path_factory.mktemp("paper") / "raw"
    write_synthetic(folder, SynthConfig(recordings=1, minutes=0.25, seed=5))
    return folder


def paper_command(raw: Path, out: Path, *more: str) -> list[str]:
    options = ["--batch-size", "64", "--threads", "1", "--jobs", "1", "--device", "cpu"]
    return aigem("paper", raw, "--out", out, *options, *more)


def run_paper_command(raw: Path, out: Path, *more: str) -> TimedRun:
    """The call, and how long it took to end after its last line (timed_runs)."""
    return run_timed(paper_command(raw, out, *more))


@pytest.fixture(scope="module")
def whole(tiny_raw: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Callable[[], Path]]:
    """An uninterrupted call of 2 epochs, what the calls stopped and run again must give: started
    at once, in the background beside the tests (one core each); called, it waits for it."""
    out = tmp_path_factory.mktemp("whole") / "out"
    program = subprocess.Popen(
        paper_command(tiny_raw, out, "--epochs", "2"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )

    def finished() -> Path:
        _, stderr = program.communicate(timeout=600)
        assert program.returncode == 0, stderr
        return out

    yield finished
    if program.poll() is None:
        program.kill()
        program.communicate()


def comparable(out: Path) -> tuple[dict, str]:
    """report.json without its timings, report.md without its last section (the time taken)."""
    document = json.loads((out / "report.json").read_text())
    del document["timings"]
    text = (out / "report.md").read_text()
    return document, text[: text.index("## Time taken")]


@pytest.mark.slow
def test_a_run_stopped_by_max_hours_says_so_and_run_again_gives_the_uninterrupted_report(
    tiny_raw: Path, whole: Callable[[], Path], tmp_path: Path
) -> None:
    out, table = tmp_path / "out", ["--only", "table"]  # the paper's model alone
    no_time = ["--max-hours", "1e-9"]  # every fit stops after its first batch
    nothing = run_paper_command(tiny_raw, out, *table, "--epochs", "1", *no_time)
    assert nothing.returncode == 1 and not (out / "report.json").exists()
    assert nothing.stderr.splitlines()[-1] == (
        "error: --max-hours ended the training before a whole epoch of dmin-25m (d_min 25 m): "
        "no report; run the same command again to continue (with more time: a fit's epoch that "
        "its share of --max-hours cuts is redone)"
    )
    assert not (out / "runs" / "dmin-25m").exists()  # no epoch kept: its files went
    one = run_paper_command(tiny_raw, out, *table, "--epochs", "1")
    assert one.returncode == 0, one.stderr
    assert json.loads((out / "report.json").read_text())["finished"]
    # More epochs continue the runs (--overwrite: paper.json's epochs change); the time limit
    # cuts the second epoch, which is not kept: the models of the first are reported.
    cut = run_paper_command(tiny_raw, out, *table, "--epochs", "2", "--overwrite", *no_time)
    assert cut.returncode == 0, cut.stderr
    assert cut.stdout.strip().splitlines()[-1] == f"{UNFINISHED} (unfinished fits: dmin-25m)"
    document = json.loads((out / "report.json").read_text())
    assert not document["finished"] and document["unfinished_fits"] == ["dmin-25m"]
    models = document["fits"]["dmin-25m"]["runs"][0]["models"]
    assert {m["epochs_done"] for m in models.values()} == {1}
    markdown = (out / "report.md").read_text()
    assert markdown.splitlines()[2].startswith(f"**{UNFINISHED}**")
    assert markdown.count("(SYNTHETIC, UNFINISHED)") == 2  # the title and Table 1's heading
    finished = run_paper_command(tiny_raw, out, *table, "--epochs", "2")
    assert finished.returncode == 0, finished.stderr
    assert "UNFINISHED" not in finished.stdout + (out / "report.md").read_text()
    ours, theirs = comparable(out)[0], comparable(whole())[0]
    assert ours["finished"] and ours["fits"] == {"dmin-25m": theirs["fits"]["dmin-25m"]}
    for key in ("table1", "settings"):
        assert ours[key] == theirs[key], key
    for call in (nothing, one, cut, finished):  # each ended with its last line
        assert call.ended_within(LINGER_S), call
    # A second seed in this folder of one: its run alone trains, the first seed's is reused.
    more = run_paper_command(tiny_raw, out, *table, "--epochs", "2", "--seeds", "2")
    assert more.returncode == 0, more.stderr
    two = json.loads((out / "report.json").read_text())
    assert [key for key in two["timings"] if key.startswith("fit ")] == ["fit dmin-25m-seed1"]
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["dmin-25m", "dmin-25m-seed1"]
    runs = two["fits"]["dmin-25m"]["runs"]
    assert two["seeds"] == [0, 1] and runs[0] == ours["fits"]["dmin-25m"]["runs"][0]
    each = [run["test"]["all"]["rmse_1s_m"] for run in runs]
    cell = two["table1"]["ours"]["AiGem (this run)"]["rmse_1s_m"]
    half = 12.706 * abs(each[0] - each[1]) / 2  # t(1) * sd / sqrt(2), sd = |a - b| / sqrt(2)
    assert cell == pytest.approx(
        {"value": sum(each) / 2, "low": cell["value"] - half, "high": cell["value"] + half}
    )
    assert "mean of 2 seeds [95 % interval: the training noise]" in more.stdout
    # Back to one seed: the first seed's report, as before; the second seed's run stays.
    again = run_paper_command(tiny_raw, out, *table, "--epochs", "2")
    assert again.returncode == 0, again.stderr
    assert comparable(out)[0] == ours and (out / "runs" / "dmin-25m-seed1").is_dir()


@pytest.mark.slow
def test_a_run_killed_half_way_and_run_again_gives_the_uninterrupted_report(
    tiny_raw: Path, whole: Callable[[], Path], tmp_path: Path
) -> None:
    killed = tmp_path / "killed"
    program = subprocess.Popen(
        paper_command(tiny_raw, killed, "--epochs", "2"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    second_fit = killed / "runs" / "dmin-25m-no-concat"
    deadline = time.monotonic() + 300
    while not (second_fit / "h1s" / LAST).exists():  # the second fit's first epoch is kept
        assert program.poll() is None, program.stderr.read()
        assert time.monotonic() < deadline, "the second fit never kept an epoch"
        time.sleep(0.01)
    os.killpg(program.pid, signal.SIGINT)
    _, stderr = program.communicate(timeout=120)
    assert program.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1].startswith(f"interrupted; {killed} keeps")
    assert "Traceback" not in stderr
    assert not (killed / "report.json").exists() and not (killed / "report.md").exists()
    kept = [epochs_kept(second_fit / f"h{s}s") for s in range(1, 6)]
    assert kept == [1] * 5  # to resume: a fit's models keep their epochs together
    again = run_paper_command(tiny_raw, killed, "--epochs", "2")
    assert again.returncode == 0, again.stderr
    assert comparable(killed) == comparable(whole())
    timings = json.loads((killed / "report.json").read_text())["timings"]
    assert "fit dmin-25m" not in timings and "fit dmin-25m-no-concat" in timings  # reused
    assert sorted(p.name for p in (killed / "figures").iterdir()) == FIGURES


def test_an_interrupt_before_the_folder_is_made_claims_no_folder(
    tiny_raw: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import aigem.paper.experiments

    out = tmp_path / "p2"
    made: list[bool] = []

    def interrupted(*_args: object) -> None:
        if made:
            out.mkdir()
        raise KeyboardInterrupt

    monkeypatch.setattr(aigem.paper.experiments, "run_paper", interrupted)
    args = ["paper", str(tiny_raw), "--out", str(out), "--device", "cpu", "--epochs", "1"]
    before = CliRunner().invoke(app, args)
    assert (before.exit_code, before.stderr) == (130, "interrupted; nothing written\n")
    made.append(True)
    after = CliRunner().invoke(app, args)
    assert (after.exit_code, after.stderr) == (
        130,
        f"interrupted; {out} keeps the finished builds and each model's last finished epoch, "
        "and no report; run the same command again to continue\n",
    )
    assert list(out.iterdir()) == []  # no log in a folder that is not the paper's


def test_a_build_held_to_other_limits_is_not_reused(tiny_build: Path, tmp_path: Path) -> None:
    """A build made through the library with other limits than its source's has the paper's
    config but not its rows: it is refused, naming the limit."""
    other = Path(shutil.copytree(tiny_build, tmp_path / "other"))
    values = json.loads((other / "manifest.json").read_text())
    values["limits"]["max_jump_m"] = 20.0
    values["config_hash"] = settings_sha256(values["config"], values["limits"])  # as built so
    write_manifest_json(other, values)
    manifest = open_build(other).manifest
    (built_from,) = {Path(f.path).parent for f in manifest.inputs}
    assert build_state(other, manifest.config, list_inputs([built_from])) == (
        "holds the rows to other physical limits than its source's (max_jump_m 20.0 -> 10.0)"
    )


def test_the_command_into_a_log_prints_each_stage_and_each_models_epochs(
    tiny_raw: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """stderr is not a terminal here (a log): every line after its wall-clock time; a line at
    the end of each build stage, each model's train and validation loss at each epoch's end,
    and the report (the lines every PLAIN_PROGRESS_INTERVAL_S within a stage set out of reach
    here), none twice."""
    from ngsim_cli import progress

    monkeypatch.setattr(progress, "PLAIN_PROGRESS_INTERVAL_S", 1e9)
    out = tmp_path / "out"
    options = ["--only", "table", "--epochs", "1", "--batch-size", "64", "--threads", "1"]
    args = ["paper", str(tiny_raw), "--out", str(out), *options, "--jobs", "1", "--device", "cpu"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    lines = result.stderr.splitlines()
    assert all(re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d ", line) for line in lines), lines
    said = [re.sub(r", \d:\d\d:\d\d elapsed$", "", line[20:]) for line in lines]
    assert said[:4] == [
        "builds: reading trajectories-0750am-0805am.txt: 1/1 (100%)",  # one job: by name
        "builds: cleaning recordings: 1/1 (100%)",
        "builds: building recordings: 1/1 (100%)",
        "builds: writing samples: 1/1 (100%)",
    ]
    mse = r"\d+\.\d{3} m²"
    for line, horizon_s in zip(said[4:9], range(1, 6), strict=True):
        assert re.fullmatch(
            rf"fit d_min 25 m, {horizon_s} s model, epoch 1: train MSE {mse}, validation MSE "
            rf"{mse} \(best\); \d+ s training at [\d,]+ graphs/s, \d+ s validation",
            line,
        ), line
    assert re.fullmatch(r"evaluating d_min 25 m: (\d+)/\1 \(100%\)", said[9])  # the bar's end
    assert re.fullmatch(r"writing the report: (\d+)/\1 \(100%\)", said[10]) and len(said) == 11
    logged = (out / PAPER_LOG).read_text().splitlines()  # the same lines, in the paper's log
    assert all(re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d ", line) for line in logged), logged
    assert [re.sub(r", \d:\d\d:\d\d elapsed$", "", line[20:]) for line in logged] == said
    assert (
        "AiGem RMSE at 1..5 s (m, in brackets its 95 % interval: the test-set noise): "
        in result.stdout
    )
