"""The correction of a run's reference for an out-of-tolerance equipment error, as the
reprocessing path applies it (`calib impact`, docs/impact.md): the corrected segments and
recorded temperature, and the ``reference_correction`` step that records it.

Kept apart from `pipelines.impact` (which re-solves through process and reprocess) so that
reprocessing carries a revision's correction without importing the look-back itself.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from calib_core.calibration import StepRecord
from calib_core.reference_errors import ReferenceError, correct_segments
from storage import queries
from storage.db import Archive


def correction_step(
    equipment_serial: str,
    kind: str,
    error: ReferenceError,
    stats: dict[str, Any],
    impact: dict | None,
) -> StepRecord:
    """The step record of a corrected solve: the correction (settings) and what it did."""
    return StepRecord(
        "reference_correction",
        settings={
            "equipment_serial": equipment_serial,
            "equipment_kind": kind,
            "quantity": error.quantity,
            "value": error.value,
            "unit": error.unit,
            **({"face": error.face, "about": error.about} if error.face else {}),
        },
        statistics={**stats, **({"impact": impact} if impact is not None else {})},
    )


def corrector(
    equipment_serial: str,
    kind: str,
    error: ReferenceError,  # noqa: ANN202
    impact: dict | None = None,
):
    """The correction of a loaded run's reference, as `process_run(correct=...)` takes it."""

    def correct(loaded):  # noqa: ANN001, ANN202 - a LoadedRun in, (LoadedRun, StepRecord) out
        segments, stats = correct_segments(loaded.segments, error)
        loaded = replace(loaded, segments=segments)
        if error.quantity == "temperature_offset_c":
            loaded, stats = _corrected_temperature(loaded, error, stats)
        step = correction_step(equipment_serial, kind, error, stats, impact)
        return loaded, step

    return correct


def _corrected_temperature(loaded, error: ReferenceError, stats: dict[str, Any]):  # noqa: ANN001, ANN202
    """The run's recorded temperature (environment.temperature_c, the chamber's reading)
    as it truly was: reading - E. It is the temperature of the run's parameters in the
    archive, the lab conditions' and a thermal campaign's (pipelines.thermal_campaign)."""
    env = loaded.manifest.environment
    t = env.temperature_c
    if t is None:
        if stats["what"].endswith("degC"):  # no chamber channel either
            return loaded, {
                **stats,
                "affected": False,
                "what": "the run recorded no chamber temperature (environment.temperature_c, "
                "chamber_temperature channel)",
            }
        return loaded, stats
    after = float(t) - error.value
    manifest = replace(loaded.manifest, environment=replace(env, temperature_c=after))
    stats = {
        **stats,
        "what": f"{stats['what']}; recorded temperature {t:g} -> {after:g} degC",
        "temperature_c": {"before": float(t), "after": after},
    }
    return replace(loaded, manifest=manifest), stats


def carried_correction(archive: Archive, run_id: str):  # noqa: ANN201 - a corrector or None
    """The reference correction of the run's current revision, to apply again when the run
    is reprocessed (new software must not drop it), or None when it has none."""
    return correction_of(queries.run_summary(archive, run_id).calibration.settings)


def correction_of(settings: dict[str, Any] | None, impact: dict | None = None):  # noqa: ANN201
    """The corrector of a revision's settings (their ``reference_correction``), None when
    they hold none; `impact`: the look-back record its step carries (`corrector`)."""
    held = (settings or {}).get("reference_correction")
    if not held:
        return None
    error = ReferenceError(
        str(held["quantity"]), float(held["value"]), held.get("face"), held.get("about")
    )
    return corrector(str(held["equipment_serial"]), str(held["equipment_kind"]), error, impact)
