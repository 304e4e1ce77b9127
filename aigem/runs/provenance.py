"""The build a run was trained on, as the run records it (aigem.runs.records reads and writes the
record), and how another build differs from it.

A build's identity is its config hash and the sha256 of its manifest's bytes: builds are
byte-deterministic, so an identical rebuild keeps it. A run records it beside the build's path,
settings (its config and its source's physical limits, what the config hash covers) and fitted
scaler. Where a build's config hash is not the run's, the settings that differ are named.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ngsim_graphs.layout import manifest_path, read_manifest
from ngsim_graphs.manifest import Manifest, json_form


@dataclass(frozen=True)
class BuildIdentity:
    """A build's identity: its config hash and the sha256 of its manifest.json's bytes."""

    config_hash: str
    manifest_sha256: str


@dataclass(frozen=True)
class BuildRecord:
    """The build a model was trained on: its absolute path, identity, time step (s; NaN where a
    run records none), settings (`Manifest.settings`: its config and its source's limits, what
    the config hash covers, as JSON) and fitted scaler (as its manifest.json holds it:
    MinMaxScaler.to_dict's form, which aigem.model.data.run_scaler reads). Both mappings are the JSON
    a run records: read, never edited."""

    build_dir: Path
    identity: BuildIdentity
    time_step_s: float
    settings: dict[str, Any]
    scaler: dict[str, Any]


def build_identity(build_dir: Path) -> tuple[Manifest, BuildIdentity]:
    """A finished build's manifest and identity."""
    manifest = read_manifest(build_dir)  # refuses unfinished builds and other format versions
    digest = hashlib.sha256(manifest_path(build_dir).read_bytes()).hexdigest()
    return manifest, BuildIdentity(str(manifest.config_hash), digest)


def build_record(build_dir: Path) -> BuildRecord:
    """What a fit of the finished build `build_dir` records of it."""
    manifest, identity = build_identity(build_dir)
    return BuildRecord(
        Path(build_dir).resolve(),
        identity,
        manifest.config.time_step_s,
        manifest.settings(),
        json_form(manifest.scaler.to_dict()),
    )


def identity_difference(
    run: BuildRecord, identity: BuildIdentity, settings: dict[str, Any] | None = None
) -> str | None:
    """How a build's identity differs from the one a run recorded (None: the same build); with
    the build's `settings` (`Manifest.settings`), the settings that differ from the run's, named
    ("d_min_m 25.0 -> 50.0", "limits.max_frame_id 72000 -> 180000")."""
    recorded = run.identity
    if identity.config_hash != recorded.config_hash:
        changed = settings_changed(run.settings, settings) if settings else []
        return (
            f"its config hash {identity.config_hash[:12]} is not the run's "
            f"{recorded.config_hash[:12]}" + (f": {'; '.join(changed)}" if changed else "")
        )
    if identity.manifest_sha256 != recorded.manifest_sha256:
        return "same config, but its manifest.json differs from the run's build (other inputs, or edited)"
    return None


def _flat(settings: Any) -> dict[str, Any]:
    """A build's settings one per key, nested ones (the limits) as "limits.max_speed_mps"."""
    if not isinstance(settings, dict):
        return {}
    return {
        f"{name}.{key}" if isinstance(value, dict) else name: inner
        for name, value in settings.items()
        for key, inner in (value.items() if isinstance(value, dict) else [(name, value)])
    }


def settings_changed(before: Any, now: dict[str, Any]) -> list[str]:
    """The settings of `now` that differ from `before` (a run's build settings), in words: a
    highD build made before its limits were its own recorded max_frame_id in NGSIM's 10 Hz
    frames, so that built again it reads "limits.max_frame_id 72000 -> 180000"."""
    old, new = _flat(before), _flat(now)
    return [
        f"{name} {old.get(name)} -> {new.get(name)}"
        for name in sorted(old.keys() | new.keys())
        if old.get(name) != new.get(name)
    ]
