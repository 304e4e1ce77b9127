"""A build's manifest as typed values, and their JSON form. `layout` alone reads and writes it.

The manifest says what a build is: the config that shaped it, the physical limits its source
held the raw rows to (`limits`, beside the config; an older manifest's config held them), what
each input file and each recording gave and lost, the samples per split, the scaler fitted on
train, the warnings, and (once written) the record of every other file of the build with the
manifest's own checksum (`integrity`). On disk it is JSON with sorted keys; `to_dict` gives
exactly that JSON's value (as `json.loads` would), so a manifest read and written again is the
same bytes (an older one's limits move beside its config). Counts are numbers of rows, tracks,
edges or samples; positions are metres, as everywhere in a build.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, astuple, dataclass, field, fields, replace
from enum import Enum
from typing import Any

from ngsim_graphs import edges
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.integrity import CHECKSUM_KEY, FILES_KEY, LIMITS_KEY, build_settings
from ngsim_graphs.scaling import MinMaxScaler
from ngsim_graphs.sources.contract import FileReport, RecordingReport
from ngsim_graphs.sources.limits import PhysicalLimits

DEFAULT_DATASET = "ngsim"  # what a manifest written before the "dataset" key was built from


def json_form(value: Any) -> Any:
    """`value` as JSON gives it back: mappings with sorted keys, tuples as lists, enums as their
    values (the form of a manifest read from disk, key order included)."""
    if isinstance(value, Mapping):
        return {str(key): json_form(value[key]) for key in sorted(value)}
    if isinstance(value, list | tuple):
        return [json_form(item) for item in value]
    if isinstance(value, Enum):
        return value.value
    return value


@dataclass(frozen=True)
class ScriptRows:
    """What the cs-lstm protocol made of CS-LSTM's rows of one recording (or of a build), as
    the manifest records it (`cslstm.cslstm_windows` counts them)."""

    kept: int  # rows the script keeps (its edge filter), every split
    too_short: int  # rows of vehicles under 31 rows: the script stops on them; left out, counted
    on_grid: int  # kept rows on the grid, one per (vehicle, frame): an even Frame_ID
    unmatched: int  # of those, rows whose vehicle has no track at that step: no sample

    @property
    def samples(self) -> int:
        return self.on_grid - self.unmatched

    def plus(self, other: ScriptRows) -> ScriptRows:
        return ScriptRows(*(a + b for a, b in zip(astuple(self), astuple(other), strict=True)))


def _script_rows(values: Mapping[str, int] | None) -> ScriptRows | None:
    """The cs-lstm protocol's row counts of a JSON object (null, or absent: aigem)."""
    return None if values is None else ScriptRows(**values)


def _report_from_json(cls: type, values: object) -> Any:
    """A report dataclass (FileReport, RecordingReport) from its JSON object: lists back to
    tuples, null back to NaN for a float field (the manifest writes NaN as null)."""
    if not isinstance(values, Mapping):
        raise ValueError(f"a {cls.__name__} entry is not a mapping")
    typed = dict(values)
    for f in fields(cls):
        value = typed.get(f.name)
        if str(f.type).startswith("tuple") and isinstance(value, list):
            typed[f.name] = tuple(value)
        elif f.type == "float" and f.name in typed and value is None:
            typed[f.name] = math.nan
    return cls(**typed)


@dataclass(frozen=True)
class SourceLine:
    """A line of an input file: where a build first met something (a position outlier)."""

    file: str  # the input's path as given to the build
    line: int  # 1-based, the header included


@dataclass(frozen=True)
class RecordingEntry:
    """One recording of a build: what cleaning counted, and what it gave the build."""

    report: RecordingReport  # its first_outlier is None: `first_outlier` names the file instead
    index: int  # the recording index of its arrays and of its samples' recording_index
    name: str  # layout.recording_name(location, period)
    first_track_id: int  # its tracks are numbered from this one
    n_steps: int  # grid steps of its frame arrays
    proximity_edges: int  # vehicle pairs within d_min, once per grid step
    samples: Mapping[str, int]  # split -> samples
    first_outlier: SourceLine | None = None  # the first row dropped as a position outlier
    cslstm_rows: ScriptRows | None = None  # what the cs-lstm protocol made of CS-LSTM's rows

    @property
    def location(self) -> str:
        return self.report.location

    @property
    def period(self) -> str:
        return self.report.period

    def to_dict(self) -> dict[str, Any]:
        """The report's fields (NaN as null) beside the entry's own."""
        report = {
            k: (None if isinstance(v, float) and math.isnan(v) else v)
            for k, v in asdict(self.report).items()
        }
        outlier = None if self.first_outlier is None else asdict(self.first_outlier)
        return {
            **report,
            "first_outlier": outlier,
            "index": self.index,
            "name": self.name,
            "first_track_id": self.first_track_id,
            "n_steps": self.n_steps,
            "proximity_edges": self.proximity_edges,
            "samples": dict(self.samples),
            "cslstm_rows": None if self.cslstm_rows is None else asdict(self.cslstm_rows),
        }

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> RecordingEntry:
        own = {
            "index",
            "name",
            "first_track_id",
            "n_steps",
            "proximity_edges",
            "samples",
            "first_outlier",
            "cslstm_rows",
        }
        report = {k: v for k, v in values.items() if k not in own}
        outlier = values["first_outlier"]
        return cls(
            report=_report_from_json(RecordingReport, report),
            index=values["index"],
            name=values["name"],
            first_track_id=values["first_track_id"],
            n_steps=values["n_steps"],
            proximity_edges=values["proximity_edges"],
            samples=dict(values["samples"]),
            first_outlier=None if outlier is None else SourceLine(outlier["file"], outlier["line"]),
            cslstm_rows=_script_rows(values.get("cslstm_rows")),
        )


@dataclass(frozen=True)
class BuildCounts:
    """Totals over the build's inputs and recordings (see docs/trust.md): rows_read =
    rows_other_locations + rows_missing_values + the rows dropped before cleaning + rows."""

    rows_read: int
    rows_other_locations: int  # of locations (or recordings) the build did not choose
    rows_missing_values: int  # an empty required field
    rows_dropped: Mapping[str, int]  # per DropReason value, position outliers included
    rows: int  # 10 Hz rows into cleaning
    exact_duplicates: int
    conflicting_duplicates: int
    position_jumps: int
    gaps: int
    tracks: int
    grid_rows: int  # rows of the tracks tables
    proximity_edges: int
    samples: int  # over every split
    cslstm_rows: ScriptRows | None = None  # the cs-lstm protocol's rows (None: aigem)

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "rows_dropped": dict(self.rows_dropped)}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> BuildCounts:
        return cls(
            **{
                **values,
                "rows_dropped": dict(values["rows_dropped"]),
                "cslstm_rows": _script_rows(values.get("cslstm_rows")),
            }
        )


def _synthetic_from_json(values: Mapping[str, Any]) -> dict[str, Any]:
    """The synthetic record of a manifest's JSON value (absent from an older manifest)."""
    synthetic, inputs = values.get("synthetic"), values.get("synthetic_inputs", [])
    if synthetic is not None and not isinstance(synthetic, bool):
        raise ValueError(f"synthetic is {synthetic!r}, not true or false")
    if not isinstance(inputs, list) or not all(isinstance(path, str) for path in inputs):
        raise ValueError("synthetic_inputs is not a list of paths")
    return {"synthetic": synthetic, "synthetic_inputs": tuple(inputs)}


def _recorded_limits(values: Mapping[str, Any]) -> PhysicalLimits | None:
    """The physical limits a manifest records: beside its config; in an older manifest, inside
    it (`BuildConfig.from_dict` sets them aside there). An older highD build's max_frame_id
    counts NGSIM's 10 Hz frames (72,000: two hours), as the limits were then NGSIM's."""
    recorded = values.get(LIMITS_KEY, values["config"].get(LIMITS_KEY))
    return None if recorded is None else PhysicalLimits.from_dict(recorded)


@dataclass(frozen=True)
class Manifest:
    """What a build is (see the module docstring). `files` and `manifest_sha256` are set when
    `layout.write_manifest` writes it: the records of the build's other files, and the checksum."""

    format_version: int
    software: Mapping[str, str]  # package -> version that made the build
    dataset: str  # the data source (`sources.registry`): "ngsim", ...
    config: BuildConfig
    config_hash: str  # sha256 of `settings()`' canonical JSON
    inputs: tuple[FileReport, ...]
    recordings: tuple[RecordingEntry, ...]  # in recording index order
    splits: Mapping[str, int]  # split -> samples
    scaler: MinMaxScaler  # fitted on the train split; not is_fitted if that split is empty
    warnings: tuple[str, ...]  # splits that are empty or tiny
    counts: BuildCounts
    # files of the folders searched that are not the dataset's (nothing in them looks like it)
    skipped_files: tuple[str, ...] = ()
    # Whether every input was written by `ngsim-graphs synth` (synth.marker), told at build time;
    # None in a manifest made before it was recorded. synthetic_inputs: the inputs that were.
    synthetic: bool | None = None
    synthetic_inputs: tuple[str, ...] = ()
    # The physical limits its source applied to the raw rows (the source's own, or others the
    # build was given); None only in a manifest that records none.
    limits: PhysicalLimits | None = None
    files: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)  # integrity's records
    manifest_sha256: str | None = None  # None until written

    def sealed(self, files: Mapping[str, Mapping[str, Any]], manifest_sha256: str) -> Manifest:
        """The manifest as written: with the file records and its checksum."""
        return replace(self, files=files, manifest_sha256=manifest_sha256)

    def settings(self) -> dict[str, Any]:
        """What its config hash covers, as JSON: its config, and under "limits" the limits its
        source applied (`integrity.build_settings`); what a run records as its build's config."""
        limits = None if self.limits is None else self.limits.to_dict()
        return json_form(build_settings(self.config.to_dict(), limits))

    def to_dict(self) -> dict[str, Any]:
        """The JSON value of the manifest, keys sorted (what `json.loads` gives of the file). An
        older manifest, read, is written in today's form: its limits beside its config, which
        keeps its config hash."""
        body: dict[str, Any] = {
            "format_version": self.format_version,
            "software": dict(self.software),
            "dataset": self.dataset,
            "config": self.config.to_dict(),
            "config_hash": self.config_hash,
            "inputs": [asdict(f) for f in self.inputs],
            "recordings": [r.to_dict() for r in self.recordings],
            "splits": dict(self.splits),
            "scaler": self.scaler.to_dict(),
            "warnings": list(self.warnings),
            "counts": self.counts.to_dict(),
            "skipped_files": list(self.skipped_files),
        }
        if self.limits is not None:
            body[LIMITS_KEY] = self.limits.to_dict()
        if self.synthetic is not None:
            body |= {"synthetic": self.synthetic, "synthetic_inputs": list(self.synthetic_inputs)}
        if self.manifest_sha256 is not None:
            body |= {FILES_KEY: dict(self.files), CHECKSUM_KEY: self.manifest_sha256}
        return json_form(body)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Manifest:
        """The manifest of a JSON value; KeyError, TypeError or ValueError for another form (a
        build setting this version does not know is a ValueError)."""
        files = values.get(FILES_KEY, {} if CHECKSUM_KEY not in values else None)  # sealed: both
        if not isinstance(files, Mapping) or not all(
            isinstance(r, Mapping) for r in files.values()
        ):
            raise ValueError("no file records")
        config = BuildConfig.from_dict(values["config"])
        edges.types_of(config.edge_types)  # a build of an edge type this version does not know
        return cls(
            format_version=values["format_version"],
            software=dict(values["software"]),
            dataset=values.get("dataset", DEFAULT_DATASET),
            config=config,
            config_hash=values["config_hash"],
            inputs=tuple(_report_from_json(FileReport, f) for f in values["inputs"]),
            recordings=tuple(RecordingEntry.from_dict(r) for r in values["recordings"]),
            splits=dict(values["splits"]),
            scaler=MinMaxScaler.from_dict(values["scaler"]),
            warnings=tuple(values.get("warnings", ())),
            counts=BuildCounts.from_dict(values["counts"]),
            skipped_files=tuple(values.get("skipped_files", ())),
            **_synthetic_from_json(values),
            limits=_recorded_limits(values),
            files=dict(files),
            manifest_sha256=values.get(CHECKSUM_KEY),
        )
