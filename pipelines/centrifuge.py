"""Centrifuge procedure, the pipeline glue: run folder -> high-g model, validation, report.

The numerics are `calib_core.solvers.centrifuge`; this module reads run
folders (run.toml with segments labelled ``xp_zero_0`` .. ``zm_step_20g`` and
the table angle and rate as reference columns, see docs/centrifuge.md),
solves, validates on a repeat run and renders the report the paper gives:
per axis F, F critical, R^2, t values and the removal sequence, and RMS and
maximum error before and after compensation. The same run can also go
through `calib process` (procedure ``centrifuge``) to be archived.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from calib_core.calibration import StepRecord
from calib_core.params import AXES
from calib_core.solvers.centrifuge import AxisValidation, solve_centrifuge, validation_errors
from calib_core.solvers.centrifuge_model import (
    CentrifugeModel,
    CentrifugeSettings,
    CentrifugeStep,
    canonical_name,
)
from calib_core.solvers.centrifuge_segments import (
    model_summary,
    settings_from_dict,
    steps_from_segments,
)
from pipelines.ingest import LoadedRun, RunSource, load_run

REPORT_NAME = "centrifuge_report.txt"


@dataclass(frozen=True)
class CentrifugeOutcome:
    """What `process_centrifuge` produced.

    validation : per axis errors on the repeat run, None without one.
    report : the text report (also written to `report_path`).
    """

    folder: Path
    serial: str
    settings: CentrifugeSettings
    model: CentrifugeModel
    record: StepRecord
    repeat_folder: Path | None
    validation: dict[str, AxisValidation] | None
    report: str
    report_path: Path | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready document: settings, model summary, validation, report path."""
        return {
            "folder": str(self.folder),
            "serial": self.serial,
            "settings": self.record.settings,
            "model": model_summary(self.model),
            "parameters": {k: [e.value, e.std] for k, e in sorted(self.model.parameters().items())},
            "repeat_folder": None if self.repeat_folder is None else str(self.repeat_folder),
            "validation": None
            if self.validation is None
            else {
                a: {
                    "rms_before": v.rms_before,
                    "rms_after": v.rms_after,
                    "max_before": v.max_before,
                    "max_after": v.max_after,
                    "rms_reduction": v.rms_reduction,
                }
                for a, v in self.validation.items()
            },
            "report_path": None if self.report_path is None else str(self.report_path),
        }


def load_centrifuge_run(folder: Path) -> tuple[LoadedRun, list[CentrifugeStep]]:
    """Read a centrifuge run folder (run.toml + data) into centrifuge steps.

    Raises
    ------
    IngestError for file and manifest problems; ValueError naming the segment
    for labels or reference channels the centrifuge cannot use.
    """
    loaded = load_run(RunSource(Path(folder), "manifest"))
    fit = {k: v for k, v in loaded.segments.items() if k not in loaded.verification_labels}
    try:
        steps = steps_from_segments(fit)
    except ValueError as exc:
        raise ValueError(f"{Path(folder) / 'run.toml'}: {exc}") from None
    return loaded, steps


def centrifuge_settings(loaded: LoadedRun, **overrides: Any) -> CentrifugeSettings:
    """Settings from the manifest: [run.settings], latitude from [site] if not given there.

    `overrides` (e.g. alpha from the command line) win over the manifest.
    """
    m = loaded.manifest
    raw = dict(m.run.settings)
    if raw.get("latitude_deg") is None and m.site.latitude_deg is not None:
        raw["latitude_deg"] = m.site.latitude_deg
    raw.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return settings_from_dict(raw, m.gravity())
    except ValueError as exc:
        raise ValueError(f"{loaded.folder / 'run.toml'}: {exc}") from None


def process_centrifuge(
    folder: Path,
    repeat: Path | None = None,
    report_path: Path | None = None,
    alpha: float | None = None,
    t_test: str | None = None,
    steer: str | None = None,
) -> CentrifugeOutcome:
    """Solve a centrifuge run, validate on a repeat run, write the text report.

    Parameters
    ----------
    folder : the run folder.
    repeat : a second run of the same unit on the same fixture (validation).
    report_path : where to write the report (default ``<folder>/centrifuge_report.txt``).
    alpha, t_test, steer : significance level, t test sides and reduction
        steering, overriding the manifest's (defaults 0.05, two-sided, F-then-t).
    """
    folder = Path(folder)
    loaded, steps = load_centrifuge_run(folder)
    settings = centrifuge_settings(loaded, alpha=alpha, t_test=t_test, steer=steer)
    try:
        model, record = solve_centrifuge(steps, settings)
    except ValueError as exc:
        raise ValueError(f"{folder / 'run.toml'}: {exc}") from None
    validation = None
    if repeat is not None:
        _, repeat_steps = load_centrifuge_run(Path(repeat))
        try:
            validation = validation_errors(model, repeat_steps)
        except ValueError as exc:
            raise ValueError(f"{Path(repeat) / 'run.toml'}: {exc}") from None
    serial = loaded.manifest.unit.serial
    text = render_report(model, settings, validation, serial=serial, folder=folder, repeat=repeat)
    path = Path(report_path) if report_path is not None else folder / REPORT_NAME
    path.write_text(text, encoding="utf-8")
    return CentrifugeOutcome(
        folder, serial, settings, model, record, repeat, validation, text, path
    )


def render_report(
    model: CentrifugeModel,
    settings: CentrifugeSettings,
    validation: dict[str, AxisValidation] | None = None,
    *,
    serial: str = "",
    folder: Path | None = None,
    repeat: Path | None = None,
) -> str:
    """The centrifuge report as plain text (SI units; angles in mrad)."""
    lines = [
        "CENTRIFUGE HIGH-G ACCELEROMETER MODEL",
        f"unit: {serial}    run: {folder or ''}",
        f"latitude {settings.latitude_deg:g} deg, g = {settings.gravity:.6f} m/s^2, "
        f"Omega_V = {model.omega_v:.4e} rad/s, alpha = {settings.alpha:g} "
        f"({settings.t_test} t test, reduction steered by {settings.steer})",
        "",
        "GEOMETRY (value +- standard uncertainty; R used: "
        + (
            "from the near-1 g runs)"
            if settings.radius_from == "near_1g"
            else "refined with the models over all records)"
        ),
        f"{'position':<9}{'R 1 g run, m':>24}{'R used, m':>24}"
        f"{'phi_h 1 g, mrad':>22}{'phi_h fit, mrad':>22}",
    ]
    for mount, r in model.radius.items():
        r1, p1, p = model.radius_raw[mount], model.phi_h_1g[mount], model.phi_h[mount]
        lines.append(
            f"{mount:<9}{_pm(r1.value, r1.std, 7):>24}{_pm(r.value, r.std, 7):>24}"
            f"{_pm(p1.value * 1e3, p1.std * 1e3, 4):>22}{_pm(p.value * 1e3, p.std * 1e3, 4):>22}"
        )
    lines += _zero_shift_lines(model)
    for axis, m in model.axes.items():
        full, fit = m.reduction.full, m.fit
        lines += [
            "",
            f"AXIS {axis}",
            f"  not identifiable with these mountings (not fitted): "
            f"{', '.join(m.not_identifiable) or 'none'}",
            f"  fitted with phi_h corrections: {', '.join(m.nuisance) or 'none'}; "
            f"step scale instability {m.scale_instability:.3g}",
            f"  full model:  F = {full.F:.2f}  F crit = {full.F_crit:.2f}  "
            f"R^2 = {full.r2:.4f}  n = {full.n}  k = {full.k}",
        ]
        if m.reduction.steps:
            lines.append("  removal sequence (least significant first):")
            for i, s in enumerate(m.reduction.steps, 1):
                lines.append(
                    f"    {i}. {s.removed:<10} t = {s.t:+8.3f}  p = {s.p:.3g}  "
                    f"(t crit {s.fit.t_crit:.3f}; model F = {s.fit.F:.2f}, R^2 = {s.fit.r2:.4f})"
                )
        else:
            lines.append("  removal sequence: none (every term significant)")
        lines += [
            f"  final model: F = {fit.F:.2f}  F crit = {fit.F_crit:.2f}  R^2 = {fit.r2:.4f}  "
            f"k = {fit.k}  t crit = {fit.t_crit:.3f}",
            f"    {'term':<10}{'parameter':<16}{'value':>14}{'std':>12}{'t':>10}",
        ]
        stats = dict(zip(fit.names, fit.t, strict=True))
        for term, c, s in zip(m.terms, m.coef, m.std, strict=True):
            lines.append(
                f"    {term:<10}{canonical_name(axis, term):<16}{c:>14.6g}{s:>12.3g}"
                f"{stats[term]:>10.2f}"
            )
    if validation is not None:
        lines += [
            "",
            f"VALIDATION ON REPEAT RUN {repeat or ''} (error = reading - input, m/s^2)",
            f"{'axis':<6}{'RMS before':>12}{'RMS after':>12}{'reduction':>11}"
            f"{'max before':>12}{'max after':>12}",
        ]
        for axis, v in validation.items():
            lines.append(
                f"{axis:<6}{v.rms_before:>12.4f}{v.rms_after:>12.4f}"
                f"{100 * v.rms_reduction:>10.1f}%{v.max_before:>12.4f}{v.max_after:>12.4f}"
            )
    return "\n".join(lines) + "\n"


def _zero_shift_lines(model: CentrifugeModel) -> list[str]:
    """The zero output after each position's run against before: shift per axis and verdict."""
    if not model.zero_shift:
        return ["", "ZERO OUTPUT BEFORE / AFTER: no zero records after the runs (not checked)"]
    limit = next(iter(model.zero_shift.values())).limit
    lines = [
        "",
        f"ZERO OUTPUT AFTER - BEFORE (m/s^2, limit {limit:.4g} per axis)",
        f"{'position':<9}" + "".join(f"{a:>22}" for a in AXES) + "  result",
    ]
    for mount, z in model.zero_shift.items():
        cells = "".join(f"{_pm(d, u, 5):>22}" for d, u in zip(z.shift, z.std, strict=True))
        lines.append(f"{mount:<9}{cells}  {'pass' if z.passed.all() else 'FAIL'}")
    missing = sorted(set(model.radius) - set(model.zero_shift))
    if missing:
        lines.append(f"no zero records after the run (not checked): {', '.join(missing)}")
    return lines


def _pm(value: float, std: float, digits: int) -> str:
    return f"{value:.{digits}f} +- {std:.2g}" if math.isfinite(std) else f"{value:.{digits}f}"
