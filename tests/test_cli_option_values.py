"""Every numeric option of ngsim-graphs checked finite and in range, by the config it sets (the
library refuses the same): NaN, infinity and a value out of range are one line and exit status
2, before any input is read or anything is written."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ngsim_cli.ngsim import app as ngsim_app
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.layout import MANIFEST_NAME, write_manifest_json

TOP = "4294967295 (2**32 - 1)"  # the largest seed


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
]
SYNTH_CASES = [
    *((["--minutes", v], "--minutes must be in (0, 60]") for v in ("nan", "inf", "0")),
    *((["--seed", v], seed(v)) for v in ("-1", "4294967296")),
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
