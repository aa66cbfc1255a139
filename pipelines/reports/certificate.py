"""The calibration certificate of one archived run, as HTML and PDF (methods.md section 4).

Built from the archive, never from memory: `storage.queries.run_summary` gives
the unit, run, equipment (with the due dates valid at run time), environment,
the calibration document, its checks and the steps (the check step holds the
thresholds used and the residual diagnosis); the archived Parquet samples give
the raw-vs-calibrated plot.

Both outputs print the same sections (`sections`): unit, run, equipment,
environment, procedure, results with uncertainties, residual table and
diagnosis, repeatability, verification, verdict, recommendations and a
signature block. The HTML is one self-contained file (inline CSS, plots as
base64 PNG); the PDF is drawn by matplotlib's PdfPages (text pages, then one
page per plot), so neither a browser nor LaTeX is needed.
"""

from __future__ import annotations

import html
import textwrap
from dataclasses import dataclass, field
from datetime import date, datetime
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402
from matplotlib.backends.backend_pdf import PdfPages  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from calib_core.calibration import Calibration  # noqa: E402
from calib_core.checks import ToleranceProfile  # noqa: E402
from calib_core.units import DEG, STANDARD_GRAVITY  # noqa: E402
from calib_core.verification import (  # noqa: E402
    NEEDS_REVIEW,
    PASS,
    REPEAT_PREFIX,
    VERIFY_PREFIX,
    ResidualDiagnosis,
    diagnose_residuals,
)
from pipelines.reports import plots  # noqa: E402
from pipelines.reports.display import display, tolerance  # noqa: E402
from pipelines.reports.protocol import render_protocol  # noqa: E402

MG = 1e-3 * STANDARD_GRAVITY
A4 = (8.27, 11.69)  # inches
PDF_FONT_PT = 7.5
PDF_LINES_PER_PAGE = 92
PDF_WIDTH_CHARS = 112
RECALIBRATION_MONTHS = 12  # default interval for a passed MEMS unit (lab practice)


@dataclass
class Section:
    """One part of the certificate: a key/value list, a table or paragraphs."""

    title: str
    pairs: list[tuple[str, str]] = field(default_factory=list)
    header: list[str] = field(default_factory=list)
    rows: list[list[str]] = field(default_factory=list)
    paragraphs: list[str] = field(default_factory=list)


@dataclass
class Certificate:
    """Everything the certificate prints, gathered from the archive."""

    title: str
    verdict: str
    sections: list[Section]
    figures: dict[str, Figure]
    protocol: str


def _step(summary: dict[str, Any], name: str) -> dict[str, Any]:
    return next((s for s in summary["calibration"]["steps"] if s["name"] == name), {})


def _fmt(value: float | None, digits: int = 5) -> str:
    return "" if value is None else f"{value:.{digits}g}"


def _profile(summary: dict[str, Any]) -> ToleranceProfile | None:
    """The thresholds archived with the verdict (None for runs archived before they were)."""
    thresholds = _step(summary, "check").get("settings", {}).get("thresholds")
    return None if thresholds is None else ToleranceProfile.from_dict(thresholds)


def _date(value: Any) -> date | None:
    if value is None or isinstance(value, date):
        return value
    return date.fromisoformat(str(value))


def _check_table(checks: list[dict[str, Any]], prefix: str, unit: tuple[str, float]) -> Section:
    rows = []
    for c in checks:
        if not c["name"].startswith(prefix):
            continue
        label, sensor = c["name"].removeprefix(prefix).rsplit(":", 1)
        name, k = unit if sensor == "acc" else ("deg/s", 1.0 / DEG)
        rows.append(
            [label, sensor, f"{c['value'] * k:.4g} {name}", f"{c['limit'] * k:.4g} {name}",
             "pass" if c["passed"] else "FAIL", c.get("detail") or ""]
        )  # fmt: skip
    return Section("", header=["point", "sensor", "error", "limit", "result", "detail"], rows=rows)


def sections(summary: dict[str, Any], samples: pa.Table) -> Certificate:
    """Gather the certificate of one archived run.

    Parameters
    ----------
    summary : `storage.queries.run_summary` of the run.
    samples : the run's archived samples (`storage.queries.run_samples`).
    """
    calrow = summary["calibration"]
    cal = Calibration.from_dict(calrow["document"])
    dev = summary["device"]
    started: datetime = summary["started_at"]
    profile = _profile(summary)
    check_stats = _step(summary, "check").get("statistics", {})
    solve_step = _step(summary, "solve")
    held_out = set(solve_step.get("statistics", {}).get("held_out", []))
    checks = calrow["checks"]
    verdict = calrow["verdict"]
    out: list[Section] = []

    out.append(
        Section(
            "Unit under test",
            pairs=[
                ("Model", dev["model"]),
                ("Serial", dev["serial"]),
                ("Manufacturer", dev["manufacturer"]),
                ("Specification", dev.get("specification") or "-"),
            ],
        )
    )
    site = {k: "-" if v is None else v for k, v in (summary["site"] or {}).items()}
    out.append(
        Section(
            "Run",
            pairs=[
                ("Run id", summary["run_id"]),
                ("Date / time", f"{started:%Y-%m-%d %H:%M:%S %Z}"),
                ("Operator", summary["operator"] or "-"),
                (
                    "Site",
                    f"latitude {site.get('latitude_deg', '-')} deg, "
                    f"height {site.get('height_m', '-')} m, "
                    f"gravity model {site.get('gravity_model', '-')}",
                ),
                ("Local gravity used", f"{summary['gravity']:.6f} m/s^2"),
                ("Calibration revision", f"{calrow['revision']} (of {summary['revisions']})"),
                ("Software", f"{calrow['software_version']} ({calrow['source_revision'] or '-'})"),
                ("Raw data SHA-256", summary["raw_hash"]),
            ],
        )
    )
    eq_rows = []
    for e in summary["equipment"]:
        due = _date(e.get("calibration_due"))
        status = "-" if due is None else ("valid" if due >= started.date() else "LAPSED")
        eq_rows.append(
            [e["kind"], e.get("model") or "-", e["serial"], e.get("accuracy_class") or "-",
             "-" if due is None else due.isoformat(), status]
        )  # fmt: skip
    out.append(
        Section(
            "Equipment",
            header=["kind", "model", "serial", "accuracy class", "calibration due", "at run time"],
            rows=eq_rows,
            paragraphs=[] if eq_rows else ["No equipment recorded for this run."],
        )
    )
    env = summary["environment"] or {}
    env_units = {"temperature_c": "deg C", "humidity_pct": "%", "pressure_hpa": "hPa",
                 "warmup_min": "min", "vibration": ""}  # fmt: skip
    out.append(
        Section(
            "Environment",
            pairs=[
                (k.split("_")[0].capitalize(), f"{v} {env_units.get(k, '')}".strip())
                for k, v in env.items()
                if v is not None
            ]
            or [("-", "not recorded")],
        )
    )

    seg = np.asarray(samples.column("segment").to_pylist()) if samples.num_rows else np.array([])
    t = samples.column("t").to_numpy() if samples.num_rows else np.array([])
    seg_rows = []
    for label in dict.fromkeys(seg.tolist()):
        ts = t[seg == label]
        rate = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 and ts[-1] > ts[0] else float("nan")
        seg_rows.append(
            [label, str(len(ts)), f"{ts[-1] - ts[0]:.1f}" if len(ts) else "-", f"{rate:.1f}",
             "verification" if label in held_out else "fit"]
        )  # fmt: skip
    settings = calrow["settings"] or {}
    out.append(
        Section(
            "Procedure",
            pairs=[
                ("Procedure", summary["procedure"]),
                (
                    "Error model",
                    "f_meas = (I + M) f_true + b;  w_meas = (I + M_g) w_true + G f + b_g",
                ),
                ("Accelerometer model", str(settings.get("accel_model", "linear"))),
                ("Solver", str(cal.info.get("accel_solver", settings.get("accel_solver", "-")))),
                ("Condition number", _fmt(cal.info.get("condition_number"), 4)),
                ("Settings", ", ".join(f"{k}={v}" for k, v in settings.items()) or "defaults"),
                ("Tolerance profile", f"{calrow['profile_name']} v{calrow['profile_version']}"),
            ],
            header=["segment", "samples", "duration (s)", "rate (Hz)", "used for"],
            rows=seg_rows,
        )
    )

    by_param = {
        c["name"].removeprefix("param:"): c for c in checks if c["name"].startswith("param:")
    }
    res_rows = []
    for p in calrow["parameters"]:
        value, unit = display(p["name"], p["value"])
        std, _ = display(p["name"], p["std"])
        c = by_param.get(p["name"])
        tol = tolerance(p["name"], c)
        tol = "" if tol is None else f"{tol[0]}{tol[1]:.4g}"
        result = "" if c is None else ("pass" if c["passed"] else "FAIL")
        res_rows.append([p["name"], f"{value:+.6g}", _fmt(std, 3), unit, tol, result])
    out.append(
        Section(
            "Results (standard uncertainty, k = 1)",
            header=["parameter", "value", "std. unc.", "unit", "tolerance", "result"],
            rows=res_rows,
        )
    )

    limits = profile.residual_limits if profile else {}
    resid_rows = []
    for r in cal.residuals:
        unit, k = plots.RESIDUAL_UNITS[r.sensor]
        ok = all(abs(m) <= limits.get(f"{r.sensor}_mean", np.inf) for m in r.mean) and all(
            s <= limits.get(f"{r.sensor}_std", np.inf) for s in r.std
        )
        resid_rows.append(
            [r.segment, r.sensor, " ".join(f"{m * k:+.3f}" for m in r.mean),
             " ".join(f"{s * k:.3f}" for s in r.std), unit, str(r.n), "pass" if ok else "FAIL"]
        )  # fmt: skip
    if "diagnosis" in check_stats:
        diagnosis = ResidualDiagnosis.from_dict(check_stats["diagnosis"])
    elif profile is not None:
        diagnosis = diagnose_residuals(cal, profile)
    else:
        diagnosis = None
    resid_text = []
    if limits:
        resid_text.append(
            f"Limits: mean {limits['acc_mean'] / MG:.3g} mg, std {limits['acc_std'] / MG:.3g} mg "
            f"(accelerometer); mean {limits['gyr_mean'] / DEG:.3g} deg/s, std "
            f"{limits['gyr_std'] / DEG:.3g} deg/s (gyro)."
        )
    if diagnosis is not None:
        worst = "; ".join(
            f"{w.segment} {w.sensor} {w.stat} (axis {w.axis}) at {w.ratio:.2f} x limit"
            for w in diagnosis.worst
        )
        resid_text.append(f"Worst segments: {worst}.")
        resid_text += diagnosis.advice
    out.append(
        Section(
            "Residuals (measured - model) per segment",
            header=["segment", "sensor", "mean x y z", "std x y z", "unit", "n", "result"],
            rows=resid_rows,
            paragraphs=resid_text,
        )
    )

    rep_rows = []
    for c in checks:
        if c["name"].startswith(REPEAT_PREFIX):
            rule = (c.get("detail") or "").split(":", 1)[0].removeprefix("rule ")
            rep_rows.append(
                [c["name"].removeprefix(REPEAT_PREFIX), rule, f"{c['value']:.4g}",
                 f"{c['limit']:.4g}", "pass" if c["passed"] else "FAIL"]
            )  # fmt: skip
    group = check_stats.get("repeatability_group", [])
    rules = profile.repeatability if profile else {}
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
    out.append(
        Section(
            "Repeatability",
            header=["parameter", "rule", "value", "limit", "result"] if rep_rows else [],
            rows=rep_rows,
            paragraphs=rep_text,
        )
    )

    ver = _check_table(checks, VERIFY_PREFIX, ("mg", 1.0 / MG))
    ver.title = "Accuracy verification (points not used in the fit)"
    if not ver.rows:
        ver.header = []
        ver.paragraphs = ["No verification points were marked for this run."]
    out.append(ver)

    failed = [c["name"] for c in checks if not c["passed"]]
    out.append(
        Section(
            "Verdict",
            pairs=[
                ("Overall result", verdict.upper()),
                ("Judged by", f"profile {calrow['profile_name']} v{calrow['profile_version']}"),
                ("Checks", f"{len(checks)} checked, {len(failed)} failed"),
                ("Failed", ", ".join(failed) or "none"),
            ],
        )
    )
    out.append(
        Section("Recommendations", paragraphs=_recommendations(verdict, cal, diagnosis, env))
    )
    out.append(
        Section(
            "Signatures",
            pairs=[
                ("Customer representative", "______________________   Date: __________"),
                ("Quality control", "______________________   Date: __________"),
                ("Production", "______________________   Date: __________"),
            ],
        )
    )

    figures: dict[str, Figure] = {}
    if cal.residuals:
        figures["Residuals per segment"] = plots.residuals_figure(
            [r.__dict__ for r in cal.residuals], limits
        )
    if samples.num_rows:
        acc = np.column_stack([samples.column(f"acc_{a}").to_numpy() for a in "xyz"])
        gyr = np.column_stack([samples.column(f"gyr_{a}").to_numpy() for a in "xyz"])
        figures["Raw vs calibrated specific-force norm"] = plots.norm_figure(seg, acc, cal, gyr)
    if cal.info.get("allan"):
        figures["Allan deviation"] = plots.allan_figure(cal.info["allan"])
    if cal.info.get("thermal"):
        figures["Thermal curves"] = plots.thermal_figure(cal.info["thermal"])

    protocol = render_protocol(
        device_model=dev["model"],
        serial=dev["serial"],
        started_at=started,
        run_id=summary["run_id"],
        procedure=summary["procedure"],
        profile=f"{calrow['profile_name']} v{calrow['profile_version']}",
        gravity=summary["gravity"],
        operator=summary["operator"] or "",
        parameters=calrow["parameters"],
        checks=checks,
        verdict=verdict,
    )
    title = f"Calibration certificate {dev['model']} {dev['serial']}"
    return Certificate(title, verdict, out, figures, protocol)


def _recommendations(
    verdict: str, cal: Calibration, diagnosis: ResidualDiagnosis | None, env: dict[str, Any]
) -> list[str]:
    out = []
    if verdict == PASS:
        out.append(
            f"Release the unit with this calibration; recalibrate within {RECALIBRATION_MONTHS} "
            "months, or earlier after a shock, a repair or a drift seen in use."
        )
    elif verdict == NEEDS_REVIEW:
        out.append(
            "The calibration is within tolerance but does not repeat against earlier runs: "
            "a quality engineer decides; repeat the calibration under controlled conditions."
        )
    else:
        out.append("Do not release the unit with this calibration; act on the failed checks.")
    if diagnosis is not None and not diagnosis.passed:
        out += diagnosis.advice
    if cal.info.get("thermal"):
        out.append("Apply the archived temperature compensation model in use.")
    else:
        temp = env.get("temperature_c")
        at = f" at {temp} deg C" if temp is not None else ""
        out.append(
            f"Calibrated{at} only: for use over a wide temperature range run a thermal "
            "campaign (e.g. -10, 0, 20, 40, 60 deg C) and apply temperature compensation."
        )
    return out


# --- HTML --------------------------------------------------------------------------------

_CSS = """
body { font-family: Helvetica, Arial, sans-serif; font-size: 10pt; margin: 2em; color: #111; }
h1 { font-size: 16pt; } h2 { font-size: 12pt; border-bottom: 1px solid #999; margin-top: 1.4em; }
table { border-collapse: collapse; margin: 0.4em 0; }
td, th { border: 1px solid #bbb; padding: 2px 6px; font-size: 9pt; text-align: left; }
th { background: #eee; } td.FAIL { color: #b00; font-weight: bold; }
.verdict { font-size: 14pt; font-weight: bold; padding: 4px 10px; display: inline-block; }
.pass { background: #cfc; } .fail { background: #fcc; } .needs-review { background: #ffc; }
img { max-width: 100%; }
"""


def render_html(cert: Certificate) -> str:
    """The certificate as one self-contained HTML document (plots embedded as base64 PNG)."""
    e = html.escape
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{e(cert.title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{e(cert.title)}</h1>",
        f'<p class="verdict {cert.verdict.replace(" ", "-")}">'
        f"Verdict: {e(cert.verdict.upper())}</p>",
    ]
    for sec in cert.sections:
        parts.append(f"<h2>{e(sec.title)}</h2>")
        if sec.pairs:
            parts.append("<table>")
            parts += [f"<tr><th>{e(k)}</th><td>{e(v)}</td></tr>" for k, v in sec.pairs]
            parts.append("</table>")
        if sec.header:
            parts.append("<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in sec.header) + "</tr>")
            for row in sec.rows:
                cells = "".join(
                    f'<td class="{e(c)}">{e(c)}</td>' if c == "FAIL" else f"<td>{e(c)}</td>"
                    for c in row
                )
                parts.append(f"<tr>{cells}</tr>")
            parts.append("</table>")
        parts += [f"<p>{e(p)}</p>" for p in sec.paragraphs]
    if cert.figures:
        parts.append("<h2>Plots</h2>")
    for name, fig in cert.figures.items():
        data = plots.to_png_base64(fig)
        parts.append(
            f'<figure><img alt="{e(name)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{e(name)}</figcaption></figure>"
        )
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


# --- PDF ---------------------------------------------------------------------------------


def _text_lines(cert: Certificate) -> list[tuple[str, str]]:
    """(style, text) lines of the text pages; style "title", "verdict", "head" or "mono"."""
    banner = f"Verdict: {cert.verdict.upper()}"
    lines: list[tuple[str, str]] = [("title", cert.title), ("verdict", banner), ("mono", "")]
    wrap = textwrap.TextWrapper(width=PDF_WIDTH_CHARS, subsequent_indent="  ")
    for sec in cert.sections:
        lines += [("mono", ""), ("head", sec.title)]
        width = max((len(k) for k, _ in sec.pairs), default=0)
        for k, v in sec.pairs:
            lines += [("mono", s) for s in wrap.wrap(f"{k:<{width}} : {v}")]
        if sec.header:
            table = [sec.header, *sec.rows]
            # The free-text detail column of check tables goes last and may be cut.
            widths = [max(len(r[i]) for r in table) for i in range(len(sec.header))]
            for row in table:
                text = "  ".join(f"{c:<{w}}" for c, w in zip(row, widths, strict=True))
                lines.append(("mono", text[:PDF_WIDTH_CHARS]))
        for p in sec.paragraphs:
            lines += [("mono", s) for s in wrap.wrap(p)]
    return lines


def render_pdf(cert: Certificate, path: Path) -> Path:
    """Write the certificate as PDF: A4 text pages, then one page per plot."""
    path = Path(path)
    lines = _text_lines(cert)
    with matplotlib.rc_context({"pdf.fonttype": 3}), PdfPages(path) as pdf:
        # Type 3 fonts (matplotlib's default) keep the text extractable and searchable
        # and are subset quickly; Type 42 embedding costs seconds per document.
        pages = [
            lines[i : i + PDF_LINES_PER_PAGE] for i in range(0, len(lines), PDF_LINES_PER_PAGE)
        ]
        for n, page in enumerate(pages, start=1):
            fig = Figure(figsize=A4)
            y = 0.965
            for style, text in page:
                if style == "title":
                    fig.text(0.06, y, text, size=14, weight="bold")
                elif style == "verdict":
                    colour = {PASS: "#070", NEEDS_REVIEW: "#a60"}.get(cert.verdict, "#b00")
                    fig.text(0.06, y - 0.004, text, size=11, weight="bold", color=colour)
                elif style == "head":
                    fig.text(0.06, y, text, size=9.5, weight="bold", color="#123")
                else:
                    colour = "#b00" if "FAIL" in text or text.endswith(": FAIL") else "black"
                    fig.text(0.06, y, text, size=PDF_FONT_PT, family="monospace", color=colour)
                y -= 0.0102
            fig.text(0.06, 0.02, f"{cert.title}  -  verdict {cert.verdict.upper()}", size=7)
            fig.text(0.9, 0.02, f"page {n}", size=7)
            pdf.savefig(fig)
        for name, fig in cert.figures.items():
            fig.suptitle(name, fontsize=10)
            fig.tight_layout()
            pdf.savefig(fig)
    return path


def write_reports(
    summary: dict[str, Any], samples: pa.Table, folder: Path, *, pdf: bool = True
) -> dict[str, Path]:
    """Write `<serial>_result.txt`, `<serial>_<run>_certificate.html` (and `.pdf`) into `folder`.

    Returns
    -------
    {"protocol": path, "html": path, "pdf": path (when written)}.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cert = sections(summary, samples)
    serial, run_id = summary["device"]["serial"], summary["run_id"]
    out = {"protocol": folder / f"{serial}_result.txt"}
    out["protocol"].write_text(cert.protocol, encoding="utf-8")
    stem = f"{serial}_{run_id}_certificate"
    if pdf:
        # PDF first: render_html closes the figures after embedding them.
        out["pdf"] = render_pdf(cert, folder / f"{stem}.pdf")
    out["html"] = folder / f"{stem}.html"
    out["html"].write_text(render_html(cert), encoding="utf-8")
    return out


def report_run(archive, run_id: str, folder: Path | None = None, *, pdf: bool = True) -> dict:
    """Write the reports of an archived run, from the archive alone (run summary + samples).

    Parameters
    ----------
    archive : storage.db.Archive
    folder : where to write; default the run's folder in the archive.

    Returns the verdict and the written paths: {"verdict": str, "protocol": Path, ...}.
    """
    from storage import queries

    summary = queries.run_summary(archive, run_id)
    samples = queries.run_samples(archive, run_id)
    folder = folder if folder is not None else archive.root / summary["run_dir"]
    written = write_reports(summary, samples, folder, pdf=pdf)
    return {"verdict": summary["calibration"]["verdict"], **written}
