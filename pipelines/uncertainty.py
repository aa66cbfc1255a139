"""The run's uncertainty budget: equipment specifications from the manifest, the step.

The Type B sources a run can claim follow from the equipment its manifest names
(docs/uncertainty.md): a ``cube`` (fixture) gives the face-angle and turn-angle errors, a
``rate_table`` the rate and turn-angle errors; local gravity's uncertainty follows the site's
gravity model. Specifications default to `calib_core.uncertainty_sources.EquipmentSpec`'s values,
are read from an equipment's ``accuracy_class`` when it states an angle (cube: face angle; rate
table: position) or a relative error (rate table: rate), and can be set per run in
``[run.settings.uncertainty]``, which wins. A run that names no equipment gets
budgets labelled Type A only (equipment unknown).
"""

from __future__ import annotations

import re
import time
from collections.abc import Mapping
from dataclasses import asdict, replace
from typing import Any

from calib_core.calibration import Calibration, StepRecord
from calib_core.preprocess.chain import settings_table
from calib_core.procedures.tables import UNCERTAINTY
from calib_core.recording import Recording
from calib_core.run_budget import budgets_doc, run_budgets
from calib_core.uncertainty import Budget
from calib_core.uncertainty_sources import EquipmentSpec
from calib_core.units import ANGLE_UNITS, DEG
from pipelines.ingest.manifest import RunManifest

# Expanded uncertainty (k = 2) of local gravity by the site's gravity model, m/s^2: a survey
# (measured), a latitude/height formula without local anomalies (helmert, wgs84: anomalies of
# up to ~100 mGal), or the standard value used anywhere on Earth (9.780 .. 9.832).
GRAVITY_EXPANDED = {"measured": 1e-4, "helmert": 2e-3, "wgs84": 2e-3, "standard": 3e-2}
# [run.settings.uncertainty] keys: (EquipmentSpec field, factor to SI).
SETTINGS = {
    "gravity_expanded_mps2": ("gravity_expanded", 1.0),
    "cube_angle_deg": ("cube_angle", DEG),
    "table_rate_rel": ("table_rate_rel", 1.0),
    "turn_angle_deg": ("turn_angle", DEG),
}

# Which specification an equipment's accuracy class gives: (kind, what it states) -> field.
ACCURACY_FIELDS = {
    ("cube", "angle"): "cube_angle",
    ("rate_table", "relative"): "table_rate_rel",
    ("rate_table", "angle"): "turn_angle",
}
_CLASS = re.compile(r"^\s*(?:\+-|±)?\s*([0-9.]+(?:[eE][-+]?[0-9]+)?)\s*(\S*)\s*$")


def accuracy_of(accuracy_class: str | None) -> tuple[str, float] | None:
    """("angle", rad) or ("relative", 1) of an equipment's accuracy class such as "0.01 deg",
    "36 arcsec", "0.01 %" or "100 ppm"; None when it states anything else (e.g. "1 ms")."""
    m = _CLASS.match(accuracy_class or "")
    if m is None:
        return None
    number, unit = float(m.group(1)), m.group(2)
    if unit in ANGLE_UNITS:
        return "angle", number * ANGLE_UNITS[unit]
    if unit in ("%", "ppm", "1", ""):
        return "relative", number * {"%": 1e-2, "ppm": 1e-6}.get(unit, 1.0)
    return None


def equipment_spec(manifest: RunManifest) -> EquipmentSpec | None:
    """The Type B specifications the run's equipment supports; None when it names none."""
    return equipment_spec_sources(manifest)[0]


def equipment_spec_sources(
    manifest: RunManifest,
) -> tuple[EquipmentSpec | None, dict[str, str]]:
    """The specification and where each of its values comes from (default, an equipment's
    accuracy class, or ``[run.settings.uncertainty]``), for the archived step record."""
    kinds = {e.kind for e in manifest.equipment}
    if not kinds:
        return None, {}
    default = EquipmentSpec()
    spec = EquipmentSpec(
        gravity_expanded=GRAVITY_EXPANDED[manifest.site.gravity_model],
        cube_angle=default.cube_angle if "cube" in kinds else None,
        table_rate_rel=default.table_rate_rel if "rate_table" in kinds else None,
        turn_angle=default.turn_angle if kinds & {"cube", "rate_table"} else None,
    )
    sources = {"gravity_expanded": f"site.gravity_model {manifest.site.gravity_model!r}"}
    sources.update(
        {
            k: "default"
            for k in ("cube_angle", "table_rate_rel", "turn_angle")
            if getattr(spec, k) is not None
        }
    )
    for e in manifest.equipment:
        stated = accuracy_of(e.accuracy_class)
        field_name = None if stated is None else ACCURACY_FIELDS.get((e.kind, stated[0]))
        if field_name is not None:
            spec = replace(spec, **{field_name: stated[1]})
            sources[field_name] = f"accuracy_class {e.accuracy_class!r} of {e.kind} {e.serial}"
    given = settings_table(manifest.run.settings, "uncertainty", UNCERTAINTY) or {}
    for key, value in given.items():
        field_name, factor = SETTINGS[key]
        spec = replace(spec, **{field_name: float(value) * factor})
        sources[field_name] = f"run.settings.uncertainty.{key}"
    return spec, sources


def uncertainty_step(
    cal: Calibration,
    segments: Mapping[str, Recording],
    settings: Mapping[str, Any],
    manifest: RunManifest,
) -> tuple[dict[str, Budget], StepRecord]:
    """The budgets of the run and the step record that archives them with the specification."""
    started = time.perf_counter()
    spec, sources = equipment_spec_sources(manifest)
    result = run_budgets(cal, segments, settings, spec)
    step = StepRecord(
        "uncertainty",
        settings={
            "equipment_spec": None if spec is None else asdict(spec),
            "equipment_spec_sources": sources,
            "equipment": sorted({e.kind for e in manifest.equipment}),
        },
        statistics={
            "budgets": budgets_doc(result),
            "seconds": round(time.perf_counter() - started, 4),
        },
    )
    return result, step
