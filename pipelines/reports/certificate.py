"""The calibration certificate of one archived run, as HTML and PDF (docs/methods.md 4.2).

Built from the archive, never from memory: `storage.queries.run_summary` gives
the unit, run, equipment (with the due dates valid at run time), environment,
the calibration document, its checks and the steps (the check step holds the
thresholds used and the residual diagnosis); the archived Parquet samples give
the raw-vs-calibrated plot.

Both outputs print the same sections (`sections`): unit, run, equipment,
environment, conditions (one verdict line per lab condition), procedure,
results with uncertainties, residual table and diagnosis, repeatability,
verification, verdict, recommendations (pipelines.reports.recommendations) and
a signature block (pipelines.reports.signatures), one function per section;
pipelines.reports.render holds them and writes the HTML, pipelines.reports.typeset
sets the PDF. pipelines.reports.run_reports reads an archived run's summary and
writes the files.

The sections that read the archived run are here in the certificate's own print
order and share one view of it (`_Archived`) and its number formatting, so that a
reviewer checking an item of ISO/IEC 17025 7.8 against the printed page finds it
in one place.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from calib_core import conditions
from calib_core.calibration import Calibration
from calib_core.tolerances import ToleranceProfile
from calib_core.verification import (
    REPEAT_PREFIX,
    VERIFY_PREFIX,
    ResidualDiagnosis,
    diagnose_residuals,
)
from pipelines.reports import figures, iso17025
from pipelines.reports.display import (
    ERROR_DIGITS,
    NO_STANDARD_U,
    RESIDUAL_UNITS,
    STANDARD_U,
    STANDARD_U_MEANING,
    U_DIGITS,
    check_counts,
    expanded_u,
    limit_text,
    number,
    quantity,
    record_notes,
    shown,
    solve_warnings,
    tolerance_text,
    uncertainty,
)
from pipelines.reports.navigation import navigation_sections
from pipelines.reports.protocol import guard_band_of, param_checks, render_protocol, verdict_of
from pipelines.reports.recommendations import recommendations
from pipelines.reports.render import Certificate, Section
from pipelines.reports.signatures import signatures_section
from pipelines.reports.validation import validation_sections

if TYPE_CHECKING:
    from calib_core.calibration import CheckResult
    from pipelines.reports.run_reports import ArchivedRun
    from storage.queries.records import DatedRevision, Revision, RunSummary


def _fmt(value: float | None, digits: int = 5) -> str:
    return "" if value is None else f"{value:.{digits}g}"


def _profile(cal: Revision) -> ToleranceProfile | None:
    """The thresholds archived with the verdict (None for runs archived before they were)."""
    thresholds = cal.step_settings("check").get("thresholds")
    return None if thresholds is None else ToleranceProfile.from_dict(thresholds)


def _check_table(checks: list[CheckResult], prefix: str) -> Section:
    """Verification errors per point and sensor in the residuals' display units."""
    rows = []
    for c in checks:
        if not c.name.startswith(prefix):
            continue
        label, sensor = c.name.removeprefix(prefix).rsplit(":", 1)
        name, k = RESIDUAL_UNITS[sensor]
        rows.append(
            [
                label,
                sensor,
                f"{number(c.value * k)} {name}",
                f"{limit_text(c.limit * k)} {name}",
                "pass" if c.passed else "FAIL",
                c.detail or "",
            ]
        )
    return Section("", header=["point", "sensor", "error", "limit", "result", "detail"], rows=rows)


@dataclass
class _Archived:
    """One archived run as the certificate's sections read it."""

    archived: ArchivedRun
    samples: pa.Table  # storage.queries.run_samples
    cal: Calibration
    profile: ToleranceProfile | None
    check_stats: dict[str, Any]  # statistics of the "check" step
    held_out: set[str]  # verification segments

    @property
    def summary(self) -> RunSummary:
        return self.archived.run

    @property
    def calrow(self) -> Revision:
        return self.archived.run.calibration

    @property
    def checks(self) -> list[CheckResult]:
        return self.calrow.checks

    @property
    def started(self) -> datetime:
        return self.archived.run.started_at


def sections(
    archived: ArchivedRun, samples: pa.Table, approvals: list[tuple[Any, bool]] | None = None
) -> Certificate:
    """Gather the certificate of one archived run, section by section.

    Parameters
    ----------
    archived : the run (`pipelines.reports.run_reports.archived_run`).
    samples : the run's archived samples (`storage.queries.run_samples`).
    approvals : the electronic approvals of the revision with whether each holds
        (`storage.approval.approval_status`); None or empty: marked not approved.
    """
    summary, calrow = archived.run, archived.run.calibration
    run = _Archived(
        archived,
        samples,
        Calibration.from_dict(calrow.document),
        _profile(calrow),
        calrow.step_statistics("check"),
        set(calrow.step_statistics("solve").get("held_out", [])),
    )
    diagnosis = _diagnosis(run)
    out = [
        iso17025.administrative_section(archived),
        _unit_section(run),
        _run_section(run),
        _equipment_section(run),
        iso17025.traceability_section(archived),
        _environment_section(run),
        _conditions_section(run),
        _procedure_section(run),
        _results_section(run),
        _uncertainty_section(run),
        _budget_section(run),
        _as_found_section(run),
        _residuals_section(run, diagnosis),
        _repeatability_section(run),
        _verification_section(run),
        _verdict_section(run),
        *navigation_sections(archived.navigation),
        *validation_sections(summary.validations),
        Section(
            "Recommendations",
            paragraphs=recommendations(
                calrow.verdict, run.cal, diagnosis, summary.environment or {}, archived.recall
            ),
        ),
        signatures_section(archived.lab, archived.chain_head, approvals or []),
    ]
    dev = summary.device
    title = f"Calibration certificate {dev.model} {dev.serial}"
    return Certificate(
        title,
        calrow.verdict,
        out,
        _figures(run),
        _protocol(run),
        iso17025.certificate_number(archived),
    )


def _unit_section(run: _Archived) -> Section:
    dev = run.summary.device
    return Section(
        "Unit under test",
        pairs=[
            ("Model", dev.model),
            ("Serial", dev.serial),
            ("Manufacturer", dev.manufacturer),
            ("Specification", dev.specification or "-"),
        ],
    )


def _run_section(run: _Archived) -> Section:
    summary, calrow = run.summary, run.calrow
    site = {k: "-" if v is None else v for k, v in (summary.site or {}).items()}
    return Section(
        "Run",
        pairs=[
            ("Run id", summary.run_id),
            ("Date / time", f"{run.started:%Y-%m-%d %H:%M:%S %Z}"),
            ("Operator", summary.operator or "-"),
            (
                "Site",
                f"latitude {site.get('latitude_deg', '-')} deg, "
                f"height {site.get('height_m', '-')} m, "
                f"gravity model {site.get('gravity_model', '-')}",
            ),
            ("Local gravity used", f"{summary.gravity:.6f} m/s^2"),
            ("Calibration revision", f"{calrow.revision} (of {summary.revisions})"),
            ("Software", f"{calrow.software_version} ({calrow.source_revision or '-'})"),
            ("Raw data SHA-256", summary.raw_hash),
        ],
    )


def _equipment_section(run: _Archived) -> Section:
    eq_rows = []
    for e in run.summary.equipment:
        due = e.calibration_due
        status = "-" if due is None else ("valid" if due >= run.started.date() else "LAPSED")
        eq_rows.append(
            [
                e.kind,
                e.model or "-",
                e.serial,
                e.accuracy_class or "-",
                "-" if due is None else due.isoformat(),
                status,
            ]
        )
    return Section(
        "Equipment",
        header=["kind", "model", "serial", "accuracy class", "calibration due", "at run time"],
        rows=eq_rows,
        paragraphs=[] if eq_rows else ["No equipment recorded for this run."],
    )


# The manifest's [environment] keys (storage.run_input.ENVIRONMENT) as printed.
ENVIRONMENT = {
    "temperature_c": ("Temperature", "deg C"),
    "temperature_drift_c_per_h": ("Temperature drift", "deg C/h"),
    "humidity_pct": ("Humidity", "%"),
    "pressure_hpa": ("Pressure", "hPa"),
    "warmup_min": ("Warm-up", "min"),
    "vibration": ("Vibration", "m/s^2 rms"),  # a level, or words (printed as they are)
}


def _environment_section(run: _Archived) -> Section:
    env = run.summary.environment or {}
    pairs = []
    for k, v in env.items():
        if v is not None:
            label, unit = ENVIRONMENT.get(k, (k, ""))
            pairs.append((label, f"{v} {unit}".strip() if not isinstance(v, str) else v))
    return Section("Environment", pairs=pairs or [("-", "not recorded")])


_RESULT_WORD = {
    "pass": "pass",
    "fail": "FAIL",
    conditions.WARNING: "WARNING",
    conditions.NOT_RECORDED: "not recorded",
    conditions.INFO: "info",
}


def _conditions_section(run: _Archived) -> Section:
    """Lab conditions and acquisition rules, one verdict line each (calib_core.conditions)."""
    rows = []
    for c in run.checks:
        key = c.name.removeprefix(conditions.CONDITION_PREFIX)
        if key == c.name:
            continue
        _, _, severity, text, unit = conditions.DEFAULT_CONDITIONS.get(key, (0, 0, "", key, ""))
        value = "" if c.value is None else f"{number(c.value)} {unit}".strip()
        rows.append(
            [text, value, _RESULT_WORD[conditions.status(c)], severity, conditions.requirement(c)]
        )
    if not rows:
        return Section(
            "Conditions",
            paragraphs=["Not checked for this run (archived before conditions were checked)."],
        )
    return Section(
        "Conditions",
        header=["condition", "value", "result", "if not met", "requirement"],
        rows=rows,
        paragraphs=[
            "A warning or an unrecorded condition leaves the verdict as it is; a "
            "failed acquisition rule fails the run."
        ],
    )


def _segments(samples: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """(segment label per sample, t per sample) of the archived samples."""
    if not samples.num_rows:
        return np.array([]), np.array([])
    return np.asarray(samples.column("segment").to_pylist()), _numbers(samples, "t")


def _numbers(samples: pa.Table, name: str) -> np.ndarray:
    """A float column of the samples as an array, read from its Arrow buffers: pyarrow's
    `to_numpy` loads pandas (about a second of CPU that nothing else of a run needs)."""
    parts = [
        np.frombuffer(c.buffers()[1], np.float64, len(c), c.offset * 8)
        if c.type == pa.float64() and not c.null_count
        else np.array(c.to_pylist(), dtype=float)  # nulls become nan
        for c in samples.column(name).chunks
    ]
    return np.concatenate(parts) if parts else np.empty(0)


def _procedure_section(run: _Archived) -> Section:
    seg, t = _segments(run.samples)
    seg_rows = []
    for label in dict.fromkeys(seg.tolist()):
        ts = t[seg == label]
        rate = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 and ts[-1] > ts[0] else float("nan")
        seg_rows.append(
            [
                label,
                str(len(ts)),
                f"{ts[-1] - ts[0]:.1f}" if len(ts) else "-",
                f"{rate:.1f}" if np.isfinite(rate) else "-",
                "verification" if label in run.held_out else "fit",
            ]
        )
    calrow, cal = run.calrow, run.cal
    settings = calrow.settings or {}
    return Section(
        "Procedure",
        pairs=[
            ("Procedure", run.summary.procedure),
            ("Error model", "f_meas = (I + M) f_true + b;  w_meas = (I + M_g) w_true + G f + b_g"),
            ("Accelerometer model", str(settings.get("accel_model", "linear"))),
            ("Solver", str(cal.info.get("accel_solver", settings.get("accel_solver", "-")))),
            ("Condition number", _fmt(cal.info.get("condition_number"), 4)),
            ("Settings", ", ".join(f"{k}={v}" for k, v in settings.items()) or "defaults"),
            ("Tolerance profile", f"{calrow.profile_name} v{calrow.profile_version}"),
        ],
        header=["segment", "samples", "duration (s)", "rate (Hz)", "used for"],
        rows=seg_rows,
    )


def _results_section(run: _Archived) -> Section:
    by_param = param_checks(run.checks)
    res_rows = []
    for p in run.calrow.parameters:
        s = shown(p.name, p.value, p.std)  # u to two digits, the value to its place
        c = by_param.get(p.name)
        tol = tolerance_text(p.name, c)
        result = "" if c is None else ("pass" if c.passed else "FAIL")
        res_rows.append([p.name, s.value, s.u or NO_STANDARD_U, s.unit, tol, result])
    return Section(
        f"Results ({STANDARD_U_MEANING})",
        header=["parameter", "value", STANDARD_U, "unit", "tolerance", "result"],
        rows=res_rows,
    )


def _decision_rule(run: _Archived) -> str:
    """The statement of the decision rule the verdicts were judged by."""
    said = run.calrow.step_settings("check").get("decision_rule")
    if said:
        return said
    return run.profile.decision_rule.statement() if run.profile else "not recorded"


def _uncertainty_section(run: _Archived) -> Section:
    budgets = run.calrow.budgets()
    by_param = param_checks(run.checks)
    rows = []
    for name, b in budgets.items():
        s = shown(name, b["value"], b["U"])  # U to two digits, the value to its place
        check = by_param.get(name)
        w = guard_band_of(check)
        rows.append(
            [
                name,
                s.signed,
                s.u,
                s.unit,
                f"{b['k']:.2f}",
                f"{b['coverage']:.0%}",
                verdict_of(check),
                w,
            ]
        )
    methods = sorted({b["k_method"] for b in budgets.values()})
    notes = sorted({n for b in budgets.values() for n in b["notes"]})
    return Section(
        "Measurement uncertainty and statement of conformity",
        header=[
            "parameter",
            "value",
            _expanded_heading(budgets),
            "unit",
            "k",
            "coverage",
            "verdict",
            "guard band w",
        ],
        rows=rows,
        paragraphs=[
            "Expanded uncertainty U = k u_c (GUM, JCGM 100:2008), coverage probability about 95 %.",
            "Budget: "
            + (
                "; ".join(sorted({b["label"] for b in budgets.values()}))
                or "not evaluated (archived before uncertainty budgets)"
            )
            + ".",
            *(f"Coverage factor k: {m}." for m in methods),
            *(f"Note: {n}." for n in notes),
            _decision_rule(run),
        ],
    )


def _expanded_heading(budgets: dict[str, dict[str, Any]]) -> str:
    """ "U (k=2)" when every budget has one coverage factor, else "U" (k per row)."""
    ks = {round(b["k"], 2) for b in budgets.values()}
    return expanded_u(ks.pop()) if len(ks) == 1 else "U"


def _budget_section(run: _Archived) -> Section:
    rows = []
    for name, b in run.calrow.budgets().items():
        for r in sorted(b["rows"], key=lambda r: -r["contribution"])[:3]:
            if r["contribution"] <= 0:
                continue
            rows.append(
                [
                    name,
                    r["source"],
                    r["kind"],
                    r["distribution"],
                    f"{r['std_input']:.3g} {r['unit']}".strip(),
                    f"{r['sensitivity']:.3g}",
                    f"{uncertainty(name, r['contribution'])} {shown(name, 0.0).unit}",
                    "inf" if r["dof"] is None else f"{r['dof']:.0f}",
                ]
            )
    return Section(
        "Uncertainty budget: dominant contributions (three largest per parameter; u(x_i) in "
        "the input's unit, u_i(y) in the parameter's display unit)",
        header=["parameter", "source", "type", "distribution", "u(x_i)", "c_i", "u_i(y)", "dof"],
        rows=rows,
    )


AS_FOUND_TITLE = "As found / as left (ISO/IEC 17025:2017 7.8.4.2)"
AS_FOUND_HEADER = [
    "parameter",
    "as found",
    "as left",
    "unit",
    "error as found",
    "U",
    "as-found verdict",
]


def _as_found_section(run: _Archived) -> Section:
    """As found (the unit with its earlier calibration) and as left (this one), 7.8.4.2."""
    step = run.calrow.step("as_found")
    if step:
        return _as_found_evaluated(step.settings, step.statistics)
    earlier = run.archived.as_found
    if not earlier:
        return Section(
            AS_FOUND_TITLE,
            paragraphs=[
                "No earlier valid calibration of this unit in the archive: no as-found values."
            ],
        )
    return _as_found_difference(run, earlier)


def _as_found_row(
    name: str, found: float, left: float, error: float, U: float | None, verdict: str | None
) -> list[str]:
    """One as-found row (SI in, the display unit out)."""
    return [
        name,
        quantity(name, found, signed=True),
        quantity(name, left, signed=True),
        shown(name, 0.0).unit,
        quantity(name, error, ERROR_DIGITS, signed=True),
        quantity(name, U, U_DIGITS),
        verdict or "-",
    ]


def _as_found_evaluated(said: dict[str, Any], stats: dict[str, Any]) -> Section:
    """The archived step "as_found" (pipelines.as_found): the earlier calibration evaluated on
    this run's data (the step's settings and statistics)."""
    earlier = (
        f"run {said['earlier_run_id']} of {said['earlier_started_at'][:10]}, revision "
        f"{said['earlier_revision']}"
    )
    if "refused" in stats:
        return Section(
            AS_FOUND_TITLE,
            paragraphs=[
                f"As found: the earlier calibration ({earlier}) could not be evaluated on this "
                f"run's data: {stats['refused']}"
            ],
        )
    rows = [
        _as_found_row(r["parameter"], r["earlier"], r["as_left"], r["error"], r["U"], r["verdict"])
        for r in stats["parameters"]
    ]
    return Section(
        AS_FOUND_TITLE,
        header=AS_FOUND_HEADER,
        rows=rows,
        paragraphs=[
            f"As found: the unit with its earlier calibration ({earlier}). Its parameters were "
            "applied to this run's raw samples and the error model solved again on the corrected "
            f"samples ({said['method']}): the error as found, judged against the tolerance with "
            "this run's U by the decision rule. As left: this calibration, to be loaded into the "
            "unit."
        ],
    )


def _as_found_difference(run: _Archived, earlier: DatedRevision) -> Section:
    """As found for runs archived before the step "as_found": as left - as found."""
    before = {p.name: p.value for p in earlier.parameters}
    budgets = run.calrow.budgets()
    rows = []
    for p in run.calrow.parameters:
        name = p.name
        if name not in before or ".noise." in name:
            continue
        error = p.value - before[name]
        U = budgets.get(name, {}).get("U")
        found = None if run.profile is None else run.profile.judge(name, error, U or 0.0)
        rows.append(_as_found_row(name, before[name], p.value, error, U, found))
    return Section(
        AS_FOUND_TITLE,
        header=AS_FOUND_HEADER,
        rows=rows,
        paragraphs=[
            f"As found: the unit with its earlier calibration (run {earlier.run_id} of "
            f"{earlier.started_at:%Y-%m-%d}, revision {earlier.revision}). This run was "
            "archived before as-found evaluation: the error as found is the first-order "
            "difference as left - as found, judged against the tolerance with this run's U by the "
            "decision rule. As left: this calibration, to be loaded into the unit."
        ],
    )


def _diagnosis(run: _Archived) -> ResidualDiagnosis | None:
    """The residual diagnosis archived with the check step, else made from the profile."""
    if "diagnosis" in run.check_stats:
        return ResidualDiagnosis.from_dict(run.check_stats["diagnosis"])
    if run.profile is not None:
        return diagnose_residuals(run.cal, run.profile)
    return None


def _residuals_section(run: _Archived, diagnosis: ResidualDiagnosis | None) -> Section:
    limits = run.profile.residual_limits if run.profile else {}
    resid_rows = []
    for r in run.cal.residuals:
        unit, k = RESIDUAL_UNITS[r.sensor]
        ok = all(abs(m) <= limits.get(f"{r.sensor}_mean", np.inf) for m in r.mean) and all(
            s <= limits.get(f"{r.sensor}_std", np.inf) for s in r.std
        )
        resid_rows.append(
            [
                r.segment,
                r.sensor,
                " ".join(f"{m * k:+.3f}" for m in r.mean),
                " ".join(f"{s * k:.3f}" for s in r.std),
                unit,
                str(r.n),
                "pass" if ok else "FAIL",
            ]
        )
    resid_text = []
    if limits:
        resid_text.append(
            "Limits: "
            + "; ".join(
                f"mean {limit_text(limits[f'{s}_mean'] * k)} {unit}, std "
                f"{limit_text(limits[f'{s}_std'] * k)} {unit} ({what})"
                for s, what in (("acc", "accelerometer"), ("gyr", "gyro"))
                for unit, k in [RESIDUAL_UNITS[s]]
            )
            + "."
        )
    if diagnosis is not None:
        worst = "; ".join(
            f"{w.segment} {w.sensor} {w.stat} (axis {w.axis}) at {w.ratio:.2f} x limit"
            for w in diagnosis.worst
        )
        resid_text.append(f"Worst segments: {worst}.")
        resid_text += diagnosis.advice
    return Section(
        "Residuals (measured - model) per segment",
        header=["segment", "sensor", "mean x y z", "std x y z", "unit", "n", "result"],
        rows=resid_rows,
        paragraphs=resid_text,
    )


def _repeatability_section(run: _Archived) -> Section:
    rep_rows = []
    for c in run.checks:
        if c.name.startswith(REPEAT_PREFIX):
            rule = (c.detail or "").split(":", 1)[0].removeprefix("rule ")
            rep_rows.append(
                [
                    c.name.removeprefix(REPEAT_PREFIX),
                    rule,
                    number(c.value),
                    limit_text(c.limit),
                    "pass" if c.passed else "FAIL",
                ]
            )
    group = run.check_stats.get("repeatability_group", [])
    rules = run.profile.repeatability if run.profile else {}
    rep_text = [
        "Rules: 'cv' = coefficient of variation of K = 1 + scale (limit cv_max); 'scatter' = "
        "chi-squared of the run-to-run scatter against the reported uncertainties (limit: its "
        f"1 - alpha/m quantile). cv_max {rules.get('cv_max', '-')}, "
        f"alpha {rules.get('alpha', '-')}."
    ]
    if rep_rows:
        rep_text.insert(0, f"Group of {len(group)} runs: {', '.join(group)}.")
    else:
        rep_text.insert(
            0,
            f"Not judged: the group had {len(group)} run(s) (this one included) when this run "
            f"was archived; {rules.get('min_runs', 3)} are needed (same serial, procedure and "
            "conditions). `calib repeatability SERIAL` judges a group later.",
        )
    return Section(
        "Repeatability",
        header=["parameter", "rule", "value", "limit", "result"] if rep_rows else [],
        rows=rep_rows,
        paragraphs=rep_text,
    )


def _verification_section(run: _Archived) -> Section:
    ver = _check_table(run.checks, VERIFY_PREFIX)
    ver.title = "Accuracy verification (points not used in the fit)"
    if not ver.rows:
        ver.header = []
        ver.paragraphs = ["No verification points were marked for this run."]
    return ver


def _verdict_section(run: _Archived) -> Section:
    calrow = run.calrow
    by_status: dict[str, list[str]] = {}
    for c in run.checks:
        by_status.setdefault(conditions.status(c), []).append(c.name)
    failed = by_status.get("fail", [])
    return Section(
        "Verdict",
        pairs=[
            ("Overall result", calrow.verdict.upper()),
            ("Judged by", f"profile {calrow.profile_name} v{calrow.profile_version}"),
            ("Decision rule", _decision_rule(run).removeprefix("Decision rule: ")),
            ("Checks", check_counts(run.checks).sentence()),
            ("Failed", ", ".join(failed) or "none"),
            ("Warnings", ", ".join(by_status.get(conditions.WARNING, [])) or "none"),
            ("Not recorded", ", ".join(by_status.get(conditions.NOT_RECORDED, [])) or "none"),
            *(_notes(run) or [("The record", "no findings, no sample replaced")]),
        ],
    )


def _notes(run: _Archived) -> list[tuple[str, str]]:
    """The findings about the record, the samples replaced and the solve's warnings."""
    return record_notes(run.checks, solve_warnings(run.calrow))


def _figures(run: _Archived) -> dict[str, str]:
    """The certificate's charts (pipelines.reports.figures), name -> SVG."""
    cal, samples = run.cal, run.samples
    out: dict[str, str] = {}
    if cal.residuals:
        limits = run.profile.residual_limits if run.profile else {}
        out |= figures.residual_figures([r.__dict__ for r in cal.residuals], limits)
    if samples.num_rows:
        seg, _ = _segments(samples)
        acc = np.column_stack([_numbers(samples, f"acc_{a}") for a in "xyz"])
        gyr = np.column_stack([_numbers(samples, f"gyr_{a}") for a in "xyz"])
        out["Raw vs calibrated specific-force norm"] = figures.norm_figure(seg, acc, cal, gyr)
    if cal.info.get("allan"):
        out |= figures.allan_figures(cal.info["allan"])
    if cal.info.get("thermal"):
        out |= figures.thermal_figures(cal.info["thermal"])
    return out


def _protocol(run: _Archived) -> str:
    summary, calrow, dev = run.summary, run.calrow, run.summary.device
    return render_protocol(
        device_model=dev.model,
        serial=dev.serial,
        started_at=run.started,
        run_id=summary.run_id,
        procedure=summary.procedure,
        profile=f"{calrow.profile_name} v{calrow.profile_version}",
        gravity=summary.gravity,
        operator=summary.operator or "",
        parameters=calrow.parameters,
        checks=run.checks,
        verdict=calrow.verdict,
        budgets=calrow.budgets(),
        decision_rule=_decision_rule(run),
        names=run.profile.protocol_names if run.profile else "canonical",
        notes=_notes(run),
    )
