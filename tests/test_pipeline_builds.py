"""`run_builds`: several builds of the same raw files, read and cleaned once, each the build
`run_build` makes of its config alone; configs that cannot share the reading refused."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from conftest import make_row, write_txt
from highd_fixtures import two_directions
from test_pipeline import hidden_siblings, snapshot

from ngsim_graphs import layout, pipeline
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.engine import stages
from ngsim_graphs.errors import NgsimInputError, NgsimOutputError
from ngsim_graphs.pipeline import SHARED_FIELDS, run_build, run_builds
from ngsim_graphs.schema import Protocol, SplitMode
from ngsim_graphs.sources.ngsim.plausibility import LIMITS
from ngsim_graphs.synth.formats import write_synthetic

D_MIN_M = (0.0, 25.0, 50.0)


@pytest.fixture(scope="module")
def raw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two synthetic recordings of half a minute: a build of each d_min has samples."""
    folder = tmp_path_factory.mktemp("raw")
    write_synthetic(folder, SynthConfig(recordings=2, minutes=0.5, seed=3))
    return folder


@pytest.fixture(scope="module")
def separate(raw: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[float, Path]:
    """The build of each d_min made alone by `run_build`."""
    root = tmp_path_factory.mktemp("separate")
    outs = {d_min: root / f"dmin-{d_min:g}" for d_min in D_MIN_M}
    for d_min, out in outs.items():
        run_build([raw], out, BuildConfig(d_min_m=d_min))
    return outs


def targets(root: Path) -> list[tuple[Path, BuildConfig]]:
    return [(root / f"dmin-{d_min:g}", BuildConfig(d_min_m=d_min)) for d_min in D_MIN_M]


@pytest.mark.parametrize("jobs", [1, 2])
def test_each_build_is_the_one_made_alone(
    raw: Path, separate: dict[float, Path], tmp_path: Path, jobs: int
) -> None:
    """Every file, the manifest included, byte for byte the separate build's, for any jobs."""
    results = run_builds([raw], targets(tmp_path), jobs=jobs)
    assert [r.out_dir for r in results] == [out for out, _ in targets(tmp_path)]
    edges = []
    for d_min, result in zip(D_MIN_M, results, strict=True):
        alone = snapshot(separate[d_min])
        assert any(name.endswith(".npy") for name in alone)
        assert snapshot(result.out_dir) == alone
        assert result.manifest == layout.read_manifest(separate[d_min])
        assert result.manifest.config.d_min_m == d_min
        edges.append(result.manifest.counts.proximity_edges)
    # The builds differ where d_min makes them: no pair is closer than 0 m, more within 50 m.
    assert edges[0] == 0 < edges[1] < edges[2]
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # no staging left


def test_builds_may_differ_in_all_but_the_shared_fields(raw: Path, tmp_path: Path) -> None:
    """The protocol, the windows, the split and d_sense too: each build the one made alone."""
    configs = {
        "cs-lstm": BuildConfig(protocol=Protocol.CS_LSTM, d_min_m=10.0),
        "aigem": BuildConfig(
            d_sense_m=30.0, history_steps=10, stride_s=4.0, split=SplitMode.RANDOM, seed=2
        ),
    }
    for name, config in configs.items():
        run_build([raw], tmp_path / "alone" / name, config)
    run_builds([raw], [(tmp_path / "together" / name, c) for name, c in configs.items()])
    for name in configs:
        assert snapshot(tmp_path / "together" / name) == snapshot(tmp_path / "alone" / name)
    cslstm = layout.read_manifest(tmp_path / "together" / "cs-lstm").counts.cslstm_rows
    assert cslstm is not None and cslstm.kept > 0  # the cs-lstm protocol's own samples


def _changed(name: str) -> Any:
    """A value of the shared field `name` other than the default's."""
    return {
        "locations": ("us-101",),
        "time_step_s": 0.4,
        "heading_smoothing_s": 2.0,
        "min_heading_speed_mps": 1.0,
    }[name]


@pytest.mark.parametrize("name", SHARED_FIELDS)
def test_configs_differing_in_what_the_reading_reads_are_refused(tmp_path: Path, name: str) -> None:
    """Refused before anything is read: the input named does not even exist."""
    first = BuildConfig()
    second = replace(first, d_min_m=50.0, **{name: _changed(name)})
    a, b = tmp_path / "a", tmp_path / "b"
    with pytest.raises(ValueError, match=rf"^{name} differs between the builds for {a} \(") as e:
        run_builds([tmp_path / "missing"], [(a, first), (b, second)])
    assert not isinstance(e.value, NgsimInputError)
    assert sorted(tmp_path.iterdir()) == []


def test_builds_are_held_to_their_sources_limits_or_to_those_given(tmp_path: Path) -> None:
    """Three vehicles in lanes 1..3 for 30 s; vehicle 2 from frame 150 on 40 ft (12.2 m)
    further along: a jump that splits its track at NGSIM's 10 m, not at 20 m. The manifest
    records the limits applied, and its config hash covers them."""
    rows = [
        make_row(v, f, 12.0 * v - 6.0, 3.0 * f + 40.0 * (v == 2 and f >= 150), lane_id=v)
        for v in (1, 2, 3)
        for f in range(300)
    ]
    path = write_txt(tmp_path / "a.txt", rows)
    own = run_build([path], tmp_path / "own", BuildConfig())
    wider = replace(LIMITS, max_jump_m=20.0)
    [given] = run_builds([path], [(tmp_path / "given", BuildConfig())], limits=wider)
    assert (own.manifest.limits, given.manifest.limits) == (LIMITS, wider)
    assert [b.manifest.counts.position_jumps for b in (own, given)] == [1, 0]
    assert [b.manifest.counts.tracks for b in (own, given)] == [4, 3]
    assert layout.read_manifest(tmp_path / "given").limits == wider
    assert own.manifest.config == given.manifest.config == BuildConfig()
    assert own.manifest.config_hash != given.manifest.config_hash


@pytest.mark.parametrize(
    ("second", "relation"), [("a", "is"), ("a/b", "lies inside"), (".", "contains")]
)
def test_outputs_that_overlap_are_refused(tmp_path: Path, second: str, relation: str) -> None:
    raw, outs = tmp_path / "raw", tmp_path / "outs"
    raw.mkdir()
    a, other = outs / "a", outs / second
    with pytest.raises(NgsimOutputError) as caught:
        run_builds([raw], [(a, BuildConfig()), (other, BuildConfig(d_min_m=0.0))])
    assert str(caught.value) == (
        f"{other}: --out {relation} the --out {a} of another build made with it; "
        "each build needs a folder of its own, apart from the others"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["raw"]


def test_an_output_inside_the_input_is_refused(raw: Path, tmp_path: Path) -> None:
    with pytest.raises(NgsimOutputError, match="--out lies inside the input"):
        run_builds([raw], [(tmp_path / "a", BuildConfig()), (raw / "b", BuildConfig())])
    assert not (tmp_path / "a").exists() and not (raw / "b").exists()


def test_a_build_in_the_way_is_refused_before_reading(raw: Path, tmp_path: Path) -> None:
    """Without --overwrite, b's earlier build stops all of them before the inputs are read."""
    a, b = tmp_path / "a", tmp_path / "b"
    (b / "arrays").mkdir(parents=True)
    (b / "arrays" / "x.npy").write_bytes(b"ours")
    seen: list[str] = []
    with pytest.raises(NgsimOutputError, match="is not a build"):
        run_builds([raw], [(a, BuildConfig()), (b, BuildConfig())], progress=seen.append)
    assert seen == [] and not a.exists() and hidden_siblings(a) == hidden_siblings(b) == []


def test_one_progress_names_the_build_of_each_stage(raw: Path, tmp_path: Path) -> None:
    stages: list[str] = []

    def progress(what: str, _done: int, _total: int) -> None:
        if not stages or stages[-1] != what:
            stages.append(what)

    run_builds([raw], targets(tmp_path)[:2], progress=progress)
    reading = [f"reading {path.name}" for path in sorted(raw.rglob("*.txt"))]
    assert stages == [
        *reading,
        "cleaning recordings",
        "building recordings (dmin-0)",
        "building recordings (dmin-25)",
        "writing samples (dmin-0)",
        "writing samples (dmin-25)",
    ]


def _interrupt_at(stage: str) -> pipeline.BuildProgress:
    def progress(what: str, _done: int, _total: int) -> None:
        if what == stage:
            raise KeyboardInterrupt

    return progress


def test_ctrl_c_while_building_leaves_no_build(raw: Path, tmp_path: Path) -> None:
    outs = [out for out, _ in targets(tmp_path)]
    with pytest.raises(KeyboardInterrupt):
        run_builds(
            [raw], targets(tmp_path), progress=_interrupt_at("building recordings (dmin-50)")
        )
    assert sorted(tmp_path.iterdir()) == []
    assert all(hidden_siblings(out) == [] for out in outs)


def test_ctrl_c_while_writing_leaves_the_builds_landed_before(
    raw: Path, separate: dict[float, Path], tmp_path: Path
) -> None:
    """Each build lands once its manifest is written: the first is finished, the others absent."""
    with pytest.raises(KeyboardInterrupt):
        run_builds([raw], targets(tmp_path), progress=_interrupt_at("writing samples (dmin-25)"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dmin-0"]
    assert snapshot(tmp_path / "dmin-0") == snapshot(separate[0.0])


def test_a_build_without_samples_stops_all_before_any_lands(raw: Path, tmp_path: Path) -> None:
    """Windows longer than any track: the third has no samples, and none of the three lands."""
    many = [*targets(tmp_path)[:2], (tmp_path / "long", BuildConfig(history_steps=2_000))]
    with pytest.raises(NgsimInputError, match="no samples: no track spans a whole window"):
        run_builds([raw], many)
    assert sorted(tmp_path.iterdir()) == []


class _Watched:
    """A BuildConfig that notes each field read of it (a property's fields through its code)."""

    def __init__(self, config: BuildConfig, read: set[str]) -> None:
        self._config, self._read = config, read

    def __getattr__(self, name: str) -> Any:
        member = getattr(type(self._config), name, None)
        if isinstance(member, property):
            return member.fget(self)  # type: ignore[misc]
        self._read.add(name)
        return getattr(self._config, name)


@pytest.mark.parametrize("dataset", ["ngsim", "highd"])
def test_reading_and_cleaning_read_only_the_shared_fields(
    raw: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, dataset: str
) -> None:
    """What makes the builds of run_builds those of run_build: the stages they share read no
    field of the config but SHARED_FIELDS (watched in this process: one job)."""
    read: set[str] = set()
    reading, cleaning = stages.read_file, stages.clean_recording

    def read_file(source: Any, path: Path, config: BuildConfig, *rest: Any) -> Any:
        return reading(source, path, _Watched(config, read), *rest)

    def clean_recording(source: Any, key: Any, staged: Any, config: BuildConfig, *rest: Any) -> Any:
        return cleaning(source, key, staged, _Watched(config, read), *rest)

    monkeypatch.setattr(stages, "read_file", read_file)
    monkeypatch.setattr(stages, "clean_recording", clean_recording)
    inputs = raw if dataset == "ngsim" else two_directions(tmp_path / "highd", number=1)
    run_build([inputs], tmp_path / "out", BuildConfig())
    assert {"locations", "time_step_s", "heading_smoothing_s"} <= read
    assert read <= set(SHARED_FIELDS)
