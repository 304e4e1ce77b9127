"""Every numeric option of both programs checked finite and in range, by the config it sets (the
library refuses the same): NaN, infinity and a value out of range are one line and exit status
2, before any input is read or anything is written; an argument that is not UTF-8 text alike.
Threads and worker processes have a ceiling (MAX_PARALLEL), and no option leaves its range to
typer's `min=`, whose error is a box of four lines."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from aigem.config import TrainConfig, horizon_steps, parse_horizons_s
from aigem.paper.plan import PaperCall
from ngsim_cli.aigem import app as aigem_app
from ngsim_cli.ngsim import app as ngsim_app
from ngsim_graphs.config import MAX_PARALLEL, BuildConfig, SynthConfig
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.layout import MANIFEST_NAME, write_manifest_json

TOP = "4294967295 (2**32 - 1)"  # the largest seed
HUGE = "99999999999"  # more threads than torch.set_num_threads' C int holds
CLI = Path(__file__).resolve().parent.parent / "cli"


def finite(option: str, value: str, bound: str) -> str:
    return f"{option} must be a finite number {bound}, not {value}"


def seed(value: str, option: str = "--seed") -> str:
    return f"{option} must be a whole number from 0 to {TOP}, not {value}"


STRIDE = "--stride-s must be a positive multiple of time_step_s (0.2 s)"
BUILD_CASES = [
    *((["--stride-s", v], STRIDE) for v in ("nan", "inf", "-0.2")),
    *((["--d-sense-m", v], finite("--d-sense-m", v, "> 0")) for v in ("nan", "inf", "0", "-1")),
    *((["--d-min-m", v], finite("--d-min-m", v, ">= 0")) for v in ("nan", "inf", "-5")),
    *(
        (["--min-heading-speed-mps", v], finite("--min-heading-speed-mps", v, ">= 0"))
        for v in ("nan", "inf", "-1")
    ),
    *(
        (["--heading-smoothing-s", v], finite("--heading-smoothing-s", v, ">= 0"))
        for v in ("nan", "inf", "-1")
    ),
    *((["--split", "random", "--seed", v], seed(v)) for v in ("-1", "4294967296")),
    (["--jobs", "0"], "--jobs must be >= 1"),
    (["--jobs", "1025"], "--jobs must be <= 1024"),
]
SYNTH_CASES = [
    *((["--minutes", v], "--minutes must be in (0, 60]") for v in ("nan", "inf", "0")),
    *((["--seed", v], seed(v)) for v in ("-1", "4294967296")),
]
FIT_CASES = [
    *((["--learning-rate", v], finite("--learning-rate", v, "> 0")) for v in ("nan", "inf", "0")),
    *((["--warmup-epochs", v], finite("--warmup-epochs", v, ">= 0")) for v in ("nan", "inf", "-1")),
    *((["--clip-grad-norm", v], finite("--clip-grad-norm", v, "> 0")) for v in ("nan", "inf", "0")),
    *((["--max-minutes", v], finite("--max-minutes", v, "> 0")) for v in ("nan", "inf", "0")),
    *((["--seed", v], seed(v)) for v in ("-1", "4294967296")),
    *(
        (["--horizon-s", v], f"--horizon-s {v}: {v} s is not a horizon in (0, 5] s")
        for v in ("nan", "inf", "-1", "0")
    ),
    *(
        (
            ["--horizon-s", v],
            f"--horizon-s {v}: a {h} s horizon is not a whole number of time steps (0.2 s)",
        )  # fmt: skip
        for v, h in (("0.3", "0.3"), ("4.9", "4.9"), ("1,2.5", "2.5"))
    ),
    (["--threads", "0"], "--threads must be >= 1"),
    (["--threads", HUGE], "--threads must be <= 1024"),
    (["--workers", "-1"], "--workers must be >= 0"),
    (["--workers", HUGE], "--workers must be <= 1024"),
]
PAPER_CASES = [
    *((["--max-hours", v], finite("--max-hours", v, "> 0")) for v in ("nan", "inf", "0")),
    *((["--seed", v], seed(v)) for v in ("-1", "4294967296")),
    (
        ["--seed", "4294967295", "--seeds", "2"],
        f"--seeds 2, --seed 4294967295: the last seed would be 4294967296, above {TOP}",
    ),
    (["--epochs", "0"], "--epochs must be >= 1"),
    (["--patience", "0"], "--patience must be >= 1"),
    (["--batch-size", "0"], "--batch-size must be >= 1"),
    (["--seeds", "0"], "--seeds must be >= 1"),
    (["--threads", "0"], "--threads must be >= 1"),
    (["--threads", HUGE], "--threads must be <= 1024"),
    (["--jobs", "0"], "--jobs must be >= 1"),
    (["--jobs", "1025"], "--jobs must be <= 1024"),
]


def _refused(app, args: list[str], message: str, tmp_path: Path) -> None:  # noqa: ANN001
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert result.stdout == "" and result.stderr == f"error: {message}\n"
    assert list(tmp_path.iterdir()) == [], "nothing is written"


@pytest.mark.parametrize(("options", "message"), BUILD_CASES)
def test_build_refuses_a_value_out_of_range(
    tmp_path: Path, options: list[str], message: str
) -> None:
    """Checked by BuildConfig before the inputs are read (there are none here)."""
    args = ["build", str(tmp_path / "raw"), "--out", str(tmp_path / "out"), *options]
    _refused(ngsim_app, args, message, tmp_path)


@pytest.mark.parametrize(("options", "message"), SYNTH_CASES)
def test_synth_refuses_a_value_out_of_range(
    tmp_path: Path, options: list[str], message: str
) -> None:
    _refused(ngsim_app, ["synth", str(tmp_path / "raw"), *options], message, tmp_path)


@pytest.mark.parametrize("value", ["-1", "4294967296"])
def test_stats_refuses_a_seed_out_of_range(tmp_path: Path, value: str) -> None:
    """Before the build is opened (there is none here)."""
    _refused(ngsim_app, ["stats", str(tmp_path / "b"), "--seed", value], seed(value), tmp_path)


@pytest.mark.parametrize(
    ("app", "args", "message"),
    [
        (ngsim_app, ["stats", "{tmp}/b", "--degree-graphs", "0"], "--degree-graphs must be >= 1"),
        (ngsim_app, ["show", "{tmp}/b", "--columns", "0"], "--columns must be >= 1"),
        (aigem_app, ["evaluate", "{tmp}/r", "--bootstrap", "-1"], "--bootstrap must be >= 0"),
    ],
)
def test_a_count_out_of_range_is_one_line(
    app, args: list[str], message: str, tmp_path: Path
) -> None:  # noqa: ANN001
    """Checked before the build or the run is opened (there is none here)."""
    _refused(app, [arg.format(tmp=tmp_path) for arg in args], message, tmp_path)


def test_no_option_leaves_its_range_to_typer() -> None:
    """typer's `min=` and `max=` answer with a box of four lines (Usage, Try, Error): every range
    is checked by a config or ngsim_graphs.config.check_count, through console.option_values."""
    bounded = re.compile(r"(^|[(,])\s*(min|max)=", re.MULTILINE)
    found = [path.name for path in sorted(CLI.glob("*.py")) if bounded.search(path.read_text())]
    assert found == []


@pytest.mark.parametrize(("options", "message"), FIT_CASES)
def test_fit_refuses_a_value_out_of_range(tmp_path: Path, options: list[str], message: str) -> None:
    """Checked by TrainConfig (and the horizons' parser) before the build is looked at."""
    args = ["fit", str(tmp_path / "b"), "--out", str(tmp_path / "run"), *options]
    _refused(aigem_app, args, message, tmp_path)


@pytest.mark.parametrize(("options", "message"), PAPER_CASES)
def test_paper_refuses_a_value_out_of_range(
    tmp_path: Path, options: list[str], message: str
) -> None:
    args = ["paper", str(tmp_path / "raw"), "--out", str(tmp_path / "out"), *options]
    _refused(aigem_app, args, message, tmp_path)


@pytest.mark.parametrize(
    ("app", "args"),
    [
        (ngsim_app, ["build", "raw", "--out", "lat\udce9"]),  # b"lat\xe9", as Python passes it
        (ngsim_app, ["stats", "b", "--plots=plots-\udce9"]),
        (aigem_app, ["fit", "b\udcff", "--out", "run"]),
    ],
)
def test_an_argument_that_is_not_utf8_is_one_line(app, args: list[str], tmp_path: Path) -> None:  # noqa: ANN001
    """Polars opens no such path and JSON records none: refused before any command runs."""
    shown = next(a for a in args if not a.isascii()).encode("utf-8", "surrogateescape")
    shown = shown.decode("utf-8", "backslashreplace")  # lat\xe9
    message = (
        f"the argument {shown} is not UTF-8 text: builds and runs record their paths as text; "
        "rename it in UTF-8"
    )
    _refused(app, args, message, tmp_path)


def test_the_configs_refuse_what_the_options_refuse() -> None:
    """The library's own refusals: the CLI only renames the settings."""
    with pytest.raises(ValueError, match=r"^d_min_m must be a finite number >= 0, not nan$"):
        BuildConfig(d_min_m=math.nan)
    with pytest.raises(ValueError, match=r"^min_heading_speed_mps must be a finite number"):
        BuildConfig(min_heading_speed_mps=math.nan)
    with pytest.raises(ValueError, match=r"^split_fractions must be three non-negative"):
        BuildConfig(split_fractions=(math.nan, 0.5, 0.5))
    with pytest.raises(ValueError, match=r"^seed must be a whole number from 0 to"):
        SynthConfig(seed=-1)
    with pytest.raises(ValueError, match=r"^horizon_s must be a multiple of the 0.2 s time step$"):
        TrainConfig(horizon_s=0.3)
    assert TrainConfig(horizon_s=1.4).horizon_steps(0.2) == 7  # 6.999999999999999 steps
    assert TrainConfig(threads=MAX_PARALLEL, workers=MAX_PARALLEL).threads == 1024
    with pytest.raises(ValueError, match=r"^threads must be <= 1024$"):
        TrainConfig(threads=MAX_PARALLEL + 1)
    with pytest.raises(ValueError, match=r"^workers must be <= 1024$"):
        TrainConfig(workers=10**11)
    with pytest.raises(ValueError, match=r"^jobs must be <= 1024$"):
        PaperCall(jobs=MAX_PARALLEL + 1)
    with pytest.raises(ValueError, match=r"^threads must be >= 1$"):
        PaperCall(threads=0)


def test_a_horizon_is_a_whole_number_of_steps_by_one_rule() -> None:
    """horizon_steps: the one rule that evaluate, predictions, the refusals and fit apply."""
    assert [horizon_steps(h) for h in (0.2, 0.6, 1.0, 4.8, 5.0)] == [1, 3, 5, 24, 25]
    assert horizon_steps(1.0, 0.5) == 2
    with pytest.raises(ValueError, match=r"^a 4.9 s horizon is not a whole number of time steps"):
        horizon_steps(4.9)
    with pytest.raises(ValueError, match=r"^a 1 s horizon is not a whole number of time steps"):
        horizon_steps(1.0, 0.3)
    with pytest.raises(ValueError, match=r"^a 0.2 s horizon is less than one time step \(0.5 s\)"):
        horizon_steps(0.2, 0.5)
    assert parse_horizons_s("1.4,0.6") == (0.6, 1.4)


def test_the_manifest_writer_refuses_a_value_json_cannot_hold(tmp_path: Path) -> None:
    """A last guard: strict JSON has no NaN; nothing is written."""
    body = {"config": {"d_min_m": math.nan}, "counts": [1.0, math.inf]}
    with pytest.raises(NgsimOutputError, match=r"config.d_min_m is nan, which JSON cannot hold"):
        write_manifest_json(tmp_path, body)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(NgsimOutputError, match=r"counts.1 is inf, which JSON cannot hold"):
        write_manifest_json(tmp_path, {"counts": [1.0, math.inf]})
    written = write_manifest_json(tmp_path, {"config": {"d_min_m": 25.0}})
    text = (tmp_path / MANIFEST_NAME).read_text()
    assert json.loads(text, parse_constant=lambda c: pytest.fail(c)) == written
