"""Out-of-tolerance look-back, the pipeline glue (`calib impact`, ISO/IEC 17025 clause 7.10;
docs/impact.md): every archived run made on a piece of reference equipment in a period,
solved again from its archived raw bytes with the reference as it truly was.

For each run: the raw files are restored (`pipelines.reprocess.restore_run`), loaded, the
reference corrected (`calib_core.reference_errors`), solved and judged as `calib process`
would, and compared with the run's current archived revision (what its certificate says):
each parameter's change in units of that revision's expanded uncertainty U, the verdict
before and after. Nothing is written unless `apply`: then each affected run gets a new
sealed revision through the reprocessing path, its reason "out-of-tolerance reference
SERIAL: QUANTITY=VALUE", its step ``reference_correction`` holding the correction and the
impact record, and its settings the correction (so the revision is not a duplicate).
"""

from __future__ import annotations

import csv
import io
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

from sqlalchemy.exc import SQLAlchemyError

from calib_core.reference_errors import ReferenceError
from pipelines.lab import customer_name
from pipelines.reference_correction import corrector
from storage import queries
from storage.db import Archive
from storage.queries.records import Revision
from storage.write_failures import describe

MOVED_MIN = 0.1  # |change| / U below which a parameter is not listed as moved
# The columns naming a run, first in both reports.
RUN_COLUMNS = ("run_id", "serial", "model", "started_at", "procedure")
CSV_COLUMNS = (*RUN_COLUMNS, "customer", "affected", "verdict_before", "verdict_after",
               "largest_move_U", "moved", "status")  # fmt: skip


def reason_of(equipment_serial: str, error: ReferenceError) -> str:
    """The reason written with every revision of an applied impact."""
    return f"out-of-tolerance reference {equipment_serial}: {error}"


def select_runs(
    archive: Archive, equipment_serial: str, since: str, until: str | None, error: ReferenceError
) -> list[dict[str, Any]]:
    """The runs of `equipment_serial` in the period whose equipment kind the error is of.

    Raises ValueError when the serial names equipment of other kinds only (the quantity
    does not belong to it), LookupError when no run used it in the period.
    """
    runs = queries.equipment_runs(archive, equipment_serial, since, until)
    if not runs:
        raise LookupError(
            f"no archived run used equipment {equipment_serial!r} between {since} and "
            f"{until or 'now'}"
        )
    kinds = sorted({r["equipment_kind"] for r in runs})
    mine = [r for r in runs if r["equipment_kind"] in error.kinds]
    if not mine:
        raise ValueError(
            f"{error.quantity} is an error of a {error.kind}; equipment {equipment_serial!r} "
            f"is a {', '.join(kinds)} in the runs of the period"
        )
    return mine


def _expanded(cal: Revision) -> dict[str, float]:
    """name -> U of the archived revision (its uncertainty step; 2 x std where absent)."""
    out = {name: float(b["U"]) for name, b in cal.budgets().items() if b.get("U")}
    for p in cal.parameters:
        if p.name not in out and p.std:
            out[p.name] = 2.0 * float(p.std)
    return out


def _moves(cal: Revision, after: dict[str, float]) -> list[dict[str, Any]]:
    """Parameters whose value changed by >= MOVED_MIN of their archived U, largest first."""
    U = _expanded(cal)
    moved = []
    for p in cal.parameters:
        name = p.name
        if name not in after or not U.get(name):
            continue
        in_U = (after[name] - float(p.value)) / U[name]
        if abs(in_U) >= MOVED_MIN:
            moved.append(
                {
                    "name": name,
                    "before": float(p.value),
                    "after": after[name],
                    "U_before": U[name],
                    "change_in_U": in_U,
                }
            )
    return sorted(moved, key=lambda m: -abs(m["change_in_U"]))


def _check_changes(cal: Revision, after: dict[str, dict]) -> list[dict[str, Any]]:
    """The checks whose outcome the correction changed (a lab condition judged at the true
    temperature, a limit now exceeded), or that only one side has."""
    before = {c.name: c.to_dict() for c in cal.checks}
    out = []
    for name in sorted(set(before) | set(after)):
        b, a = before.get(name), after.get(name)
        if b is not None and a is not None and bool(b["passed"]) == bool(a["passed"]):
            continue
        out.append(
            {
                "name": name,
                "passed_before": None if b is None else bool(b["passed"]),
                "passed_after": None if a is None else bool(a["passed"]),
                "detail": (a or b)["detail"],
            }
        )
    return out


def resolve_run(
    archive: Archive, run_id: str, equipment_serial: str, kind: str, error: ReferenceError
) -> dict[str, Any]:
    """Solve one archived run again with the corrected reference; nothing is written.

    Returns
    -------
    dict: affected (bool), what (the correction in words), verdict_after, values_after
    (name -> value) or, when the solve fails, error.
    """
    from pipelines.ingest.run_loader import load_run
    from pipelines.process import check_run, solve_loaded
    from pipelines.reprocess import restore_run

    with tempfile.TemporaryDirectory(prefix=f"impact_{run_id}_") as tmp:
        loaded = load_run(restore_run(archive, run_id, Path(tmp) / run_id, link=True))
    loaded, step = corrector(equipment_serial, kind, error)(loaded)
    out: dict[str, Any] = {"affected": step.statistics["affected"], "what": step.statistics["what"]}
    if "temperature_c" in step.statistics:
        out["temperature_c"] = step.statistics["temperature_c"]
    if not out["affected"]:
        return out
    try:
        cal, _, _, budgets, _ = solve_loaded(loaded)
        judged = check_run(loaded, cal, archive, run_id, budgets)
    except ValueError as exc:  # the corrected run no longer solves: say so, per run
        return {**out, "error": str(exc)}
    return {
        **out,
        "verdict_after": judged.verdict,
        "values_after": {n: p.value for n, p in cal.parameters.items()},
        "checks_after": {c.name: c.to_dict() for c in judged.checks},
    }


def impact(
    archive: Archive,
    equipment_serial: str,
    error: ReferenceError,
    since: str,
    until: str | None = None,
    *,
    apply: bool = False,
) -> dict[str, Any]:
    """The look-back of one equipment error over a period (module docstring).

    Returns
    -------
    JSON-ready dict: equipment_serial, error (quantity, value, unit, kind), period, reason,
    applied, customer, and ``runs``: per run its run_id, serial, model, started_at,
    procedure, revision_before, verdict_before, affected, what, verdict_after, moved
    (name, before, after, U_before, change_in_U), checks_changed (the checks whose
    outcome changed), temperature_c (before, after; a chamber offset), and with `apply`
    the status and revision of the new revision (or the error); ``campaigns``: the
    thermal models fitted again (`campaign_effects`; a chamber offset only).
    """
    runs = select_runs(archive, equipment_serial, since, until, error)
    period = {"period": {"from": str(since), "to": None if until is None else str(until)}}
    reason = reason_of(equipment_serial, error)
    customer = customer_name()
    report = []
    for run in runs:
        cal = queries.run_summary(archive, run["run_id"]).calibration
        entry = {k: run[k] for k in ("run_id", "serial", "model", "procedure")}
        entry |= {
            "started_at": run["started_at"].isoformat(),
            "revision_before": run["revision"],
            "verdict_before": run["verdict"],
            "customer": customer,
        }
        found = resolve_run(archive, run["run_id"], equipment_serial, run["equipment_kind"], error)
        entry |= {
            "affected": found["affected"],
            "what": found["what"],
            "verdict_after": found.get("verdict_after", run["verdict"]),
            "moved": _moves(cal, found.get("values_after", {})),
        }
        if "temperature_c" in found:
            entry["temperature_c"] = found["temperature_c"]
        entry["checks_changed"] = (
            _check_changes(cal, found["checks_after"]) if "checks_after" in found else []
        )
        if "error" in found:
            entry |= {"verdict_after": None, "error": found["error"]}
        if apply and found["affected"] and "error" not in found:
            entry |= _apply(archive, run, equipment_serial, error, reason, entry | period)
        report.append(entry)
    campaigns = (
        campaign_effects(archive, report, error, apply=apply, reason=reason)
        if error.quantity == "temperature_offset_c"
        else []
    )
    return {
        "campaigns": campaigns,
        "equipment_serial": equipment_serial,
        "error": {
            "quantity": error.quantity,
            "value": error.value,
            "unit": error.unit,
            "kind": error.kind,
            **({"face": error.face, "about": error.about} if error.face else {}),
        },
        **period,
        "reason": reason,
        "applied": apply,
        "customer": customer,
        "runs": report,
        "not_written": not_written(report, campaigns) if apply else [],
    }


def not_written(runs: list[dict[str, Any]], campaigns: list[dict[str, Any]]) -> list[str]:
    """The runs an applied look-back affects but did not archive a revision of (the write
    failed, or the corrected run no longer solves), then the serials whose thermal model
    was not fitted again ("thermal model of SERIAL")."""
    missed = [
        r["run_id"]
        for r in runs
        if r["affected"] and r.get("status") not in ("revised", "duplicate")
    ]
    return missed + [
        f"thermal model of {c['serial']}"
        for c in campaigns
        if c.get("status") not in ("refitted", "duplicate")
    ]


def applied_words(doc: dict[str, Any]) -> str:
    """What an impact wrote, in words: the revisions archived and those not written."""
    if not doc["applied"]:
        return "dry run: nothing archived"
    done = sum(r.get("status") == "revised" for r in doc["runs"])
    missed = doc.get("not_written") or []
    return f"{done} revision(s) archived" + (
        f"; NOT written: {', '.join(missed)}" if missed else ""
    )


def _apply(
    archive: Archive,
    run: dict[str, Any],
    equipment_serial: str,
    error: ReferenceError,
    reason: str,
    entry: dict[str, Any],
) -> dict[str, Any]:
    """Archive the corrected solve as a new sealed revision; its status and revision."""
    from pipelines.reprocess import reprocess_run

    run_id = run["run_id"]
    keys = ("verdict_before", "verdict_after", "revision_before", "moved", "checks_changed")
    keys += ("period",)
    record = {k: entry[k] for k in (*keys, "temperature_c") if k in entry}
    outcome = reprocess_run(
        archive,
        run_id,
        reason=reason,
        correct=corrector(equipment_serial, run["equipment_kind"], error, record),
    )
    got = {"status": outcome["status"]}
    if outcome["status"] == "failed":
        got["error"] = outcome["error"]
    else:
        got["revision_after"] = queries.run_summary(archive, run_id).calibration.revision
        got["verdict_after"] = outcome["verdict"]
    return got


def csv_report(doc: dict[str, Any]) -> str:
    """The look-back as CSV (one row per run, CSV_COLUMNS), for the nonconformity record."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in doc["runs"]:
        largest = r["moved"][0]["change_in_U"] if r["moved"] else 0.0
        parts = [temperature_text(r), checks_text(r)]
        parts += [f"{m['name']} {m['change_in_U']:+.2f} U" for m in r["moved"]]
        moved = "; ".join(filter(None, parts))
        w.writerow(
            (
                *(r[k] for k in RUN_COLUMNS),
                r["customer"] or "",
                r["affected"],
                r["verdict_before"],
                r["verdict_after"] or "",
                f"{largest:+.3f}",
                moved,
                status_text(r),
            )
        )
    return buf.getvalue()


# Typeset: A4 landscape (nine columns), page numbers in the footer, long words wrapped.
PRINT_CSS = (
    "@page{size:A4 landscape;margin:14mm 12mm 16mm;"
    "@bottom-right{content:'page ' counter(page) ' of ' counter(pages);font-size:8pt}}"
    "body{margin:0;font-size:9pt}table{width:100%}td{overflow-wrap:break-word}"
    "td:nth-child(-n+7){white-space:nowrap}"
)


def html_report(doc: dict[str, Any], *, for_print: bool = False) -> str:
    """The look-back as a self-contained HTML page for the nonconformity record (every
    archived string escaped); `for_print`: with the page layout of `pdf_report`."""
    from html import escape

    def cell(v: Any) -> str:
        return f"<td>{escape('' if v is None else str(v))}</td>"

    head = (
        "<tr>"
        + "".join(
            f"<th>{escape(c)}</th>"
            for c in (
                "Run",
                "Unit",
                "Model",
                "Started",
                "Procedure",
                "Verdict before",
                "Verdict after",
                "Moved (change / U before)",
                "Status",
            )
        )
        + "</tr>"
    )
    rows = []
    for r in doc["runs"]:
        moved = "; ".join(moved_text(m) for m in r["moved"])
        rows.append(
            "<tr>"
            + "".join(
                cell(v)
                for v in (
                    *(r[k] for k in RUN_COLUMNS),
                    r["verdict_before"],
                    r["verdict_after"],
                    "; ".join(filter(None, (temperature_text(r), checks_text(r), moved)))
                    or ("no parameter moved" if r["affected"] else f"not affected: {r['what']}"),
                    status_text(r),
                )
            )
            + "</tr>"
        )
    period = f"{doc['period']['from']} to {doc['period']['to'] or 'now'}"
    flipped = sum(r["verdict_before"] != r["verdict_after"] for r in doc["runs"])
    return (
        '<!DOCTYPE html>\n<html><head><meta charset="utf-8">'
        f"<title>Impact of {escape(doc['reason'])}</title>"
        "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
        "td,th{border:1px solid #999;padding:3px 6px;text-align:left}"
        + (PRINT_CSS if for_print else "")
        + "</style></head><body>"
        f"<h1>Out-of-tolerance look-back</h1><p>{escape(doc['reason'])}; runs started "
        f"{escape(period)}; customer: {escape(doc['customer'] or 'not recorded')}; "
        f"{len(doc['runs'])} run(s), {flipped} verdict(s) changed; "
        + escape(applied_words(doc))
        + f" (ISO/IEC 17025 clause 7.10).</p><table>{head}{''.join(rows)}</table>"
        + _campaigns_html(doc.get("campaigns", []))
        + "</body></html>\n"
    )


def status_text(r: dict[str, Any]) -> str:
    """What became of a run: "dry run", its outcome's status, or "failed: <error>"."""
    return r.get("status", "dry run") if "error" not in r else f"failed: {r['error']}"


def moved_text(m: dict[str, Any]) -> str:
    """One moved parameter in words: name, before -> after in SI with its unit, and the
    change in units of the archived U."""
    return (
        f"{m['name']} {m['before']:.6g} -> {m['after']:.6g}{_si_unit(m['name'])} "
        f"({m['change_in_U']:+.2f} U)"
    )


def _si_unit(name: str) -> str:
    """' m/s^2' after a value of `name` (SI, as archived); '' for a ratio (scale, misalignment)."""
    from calib_core.params import unit_of

    unit = unit_of(name)
    return "" if unit == "1" else f" {unit}"


def checks_text(r: dict[str, Any]) -> str:
    """The checks whose outcome changed, in words; "" if none."""

    def word(passed: bool | None) -> str:
        return "absent" if passed is None else ("pass" if passed else "not passed")

    return "; ".join(
        f"check {c['name']}: {word(c['passed_before'])} -> {word(c['passed_after'])}"
        for c in r.get("checks_changed", [])
    )


def temperature_text(r: dict[str, Any]) -> str:
    """A run's recorded temperature corrected (a chamber offset), in words; "" if none."""
    t = r.get("temperature_c")
    return f"temperature {t['before']:g} -> {t['after']:g} degC" if t else ""


def _campaigns_html(campaigns: list[dict[str, Any]]) -> str:
    """The thermal models fitted again with the corrected temperatures, as a table."""
    from html import escape

    if not campaigns:
        return ""
    rows = []
    for c in campaigns:
        b, a = c["range_before"], c["range_after"]
        moved = "; ".join(
            f"{m['name']} at {m['temperature_c']:g} degC {m['before']:.6g} -> {m['after']:.6g}"
            f"{_si_unit(m['name'])} ({m['change_in_U']:+.2f} U)"
            for m in c["moved"][:5]
        )
        model = f"{c['model_id']}" + (f" -> {c['model_id_after']}" if "model_id_after" in c else "")
        cells = (
            c["serial"],
            model,
            f"{b['t_min']:g} .. {b['t_max']:g} -> {a['t_min']:g} .. {a['t_max']:g} degC",
            f"{len(c['corrected'])} of {len(c['runs'])}",
            moved or "no prediction moved",
        )
        rows.append("<tr>" + "".join(f"<td>{escape(str(v))}</td>" for v in cells) + "</tr>")
    head = "".join(
        f"<th>{h}</th>"
        for h in ("Unit", "Thermal model", "Range", "Runs corrected", "Largest changes (/ U after)")
    )
    return f"<h2>Thermal models fitted again</h2><table><tr>{head}</tr>{''.join(rows)}</table>"


def pdf_report(doc: dict[str, Any]) -> bytes:
    """The look-back typeset as PDF by WeasyPrint from its HTML page (`html_report`), as
    certificates were before they were set by Typst (pipelines.reports.typeset)."""
    import weasyprint

    return weasyprint.HTML(string=html_report(doc, for_print=True)).write_pdf()


def record_doc(record: dict[str, Any]) -> dict[str, Any]:
    """An applied impact record (`storage.queries.impact.impact_records`) as the report
    document `impact` returns, for `html_report`, `csv_report` and `pdf_report`."""
    return {
        "equipment_serial": record["equipment_serial"],
        "error": {
            k: record[k] for k in ("quantity", "value", "unit", "face", "about") if record.get(k)
        },
        "period": record["period"],
        "reason": record["reason"],
        "applied": True,
        "customer": customer_name(),
        "runs": [
            {
                "run_id": r["run_id"],
                "serial": r["serial"],
                "model": r["model"],
                "started_at": r["started_at"].isoformat(),
                "procedure": r["procedure"],
                "customer": customer_name(),
                "affected": True,
                "what": r["what"],
                "revision_before": r["revision_before"],
                "revision_after": r["revision"],
                "verdict_before": r["verdict_before"],
                "verdict_after": r["verdict_after"],
                "moved": r["moved"],
                **({"temperature_c": r["temperature_c"]} if r.get("temperature_c") else {}),
                "checks_changed": r["checks_changed"],
                "status": f"revision {r['revision']}" + ("" if r["current"] else " (superseded)"),
            }
            for r in record["runs"]
        ],
    }


THERMAL_GRID = 21  # temperatures at which a refitted thermal model is compared


def campaign_effects(
    archive: Archive,
    runs: list[dict[str, Any]],
    error: ReferenceError,
    *,
    apply: bool,
    reason: str,
) -> list[dict[str, Any]]:
    """The thermal models fitted over runs whose temperatures a chamber offset moved,
    fitted again with the true temperatures (the archived model's own fit settings).

    Per model: serial, model_id, runs (of its campaign), corrected (the runs this error
    moved), range before and after (t_min, t_max, t_ref), and per parameter the largest
    change of the value it predicts (compensates to) at a true temperature of the
    refitted range, in units of its expanded uncertainty there (U = 2 x the refitted
    curve's standard uncertainty), largest first. With `apply` the refitted model is
    archived (it supersedes the unit's current one), its info holding the reason, once
    every corrected run of the campaign is revised (status "refitted", model_id_after;
    "duplicate" when the current model was fitted again for this reason already).
    """
    from calib_core import thermal
    from pipelines.thermal_campaign import campaign_from_archive, fit_campaign_step

    corrected = {
        r["run_id"]: r["temperature_c"]["after"]
        for r in runs
        if "temperature_c" in r and "error" not in r
    }
    out = []
    for serial in dict.fromkeys(r["serial"] for r in runs):
        held = queries.latest_thermal_model(archive, serial)
        used = list((held or {}).get("document", {}).get("info", {}).get("runs", []))
        hit = [run_id for run_id in used if run_id in corrected]
        if not hit:
            continue
        before = thermal.ThermalModel.from_dict(held["document"])
        fit_settings = before.info.get("step", {}).get("settings")
        points, rows = campaign_from_archive(archive, serial, used)
        if not apply:  # the archive still holds the readings: the true ones, here
            points = [
                replace(p, temperature=corrected.get(r["run_id"], p.temperature))
                for p, r in zip(points, rows, strict=True)
            ]
        after, _ = fit_campaign_step(points, fit_settings)
        entry = {
            "serial": serial,
            "model_id": held["id"],
            "runs": used,
            "corrected": hit,
            "range_before": {k: getattr(before, k) for k in ("t_min", "t_max", "t_ref")},
            "range_after": {k: getattr(after, k) for k in ("t_min", "t_max", "t_ref")},
            "moved": _curve_moves(before, after),
        }
        if apply:
            entry |= _refit(archive, serial, used, fit_settings, reason, runs, before)
        out.append(entry)
    return out


def _refit(
    archive: Archive,
    serial: str,
    used: list[str],
    fit_settings: dict[str, Any] | None,
    reason: str,
    runs: list[dict[str, Any]],
    before: Any,
) -> dict[str, Any]:
    """Archive the refitted model once every corrected run of its campaign holds its true
    temperature; its status (and id) or why not."""
    from pipelines.thermal_campaign import thermal_fit

    status = {r["run_id"]: r.get("status") for r in runs}
    pending = [i for i in used if i in status and status[i] not in ("revised", "duplicate")]
    if pending:  # a fit over a mix of readings and true temperatures would be wrong
        return {"status": "not refitted", "error": f"runs {pending} were not revised"}
    if before.info.get("reason") == reason:
        return {"status": "duplicate"}  # fitted again for this error already
    try:
        fitted = thermal_fit(archive, serial, used, fit_settings, reason=reason)
    except (OSError, SQLAlchemyError) as exc:  # the write failed: said, never a success
        return {"status": "failed", "error": describe(exc, archive.url) or str(exc)}
    return {"status": "refitted", "model_id_after": fitted["model_id"]}


def _curve_moves(before: Any, after: Any) -> list[dict[str, Any]]:
    """Per parameter of both models: the largest |before(T) - after(T)| / U_after(T) over
    the refitted range (T true temperatures), where it is and the values there."""
    import numpy as np

    grid = np.linspace(after.t_min, after.t_max, THERMAL_GRID)
    moved = []
    for name in sorted(set(before.curves) & set(after.curves)):
        U = 2.0 * after.std(name, grid)
        d = before.value(name, grid) - after.value(name, grid)
        ok = U > 0
        if not ok.any():
            continue
        ratio = np.where(ok, np.abs(d) / np.where(ok, U, 1.0), 0.0)
        i = int(np.argmax(ratio))
        was, now = float(before.value(name, grid[i])), float(after.value(name, grid[i]))
        moved.append(
            {
                "name": name,
                "temperature_c": float(grid[i]),
                "before": was,
                "after": now,
                "U_after": float(U[i]),
                "change_in_U": (now - was) / float(U[i]),
            }
        )
    return sorted(moved, key=lambda m: -abs(m["change_in_U"]))
