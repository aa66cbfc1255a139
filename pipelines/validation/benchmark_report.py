"""Ground-truth benchmark, the report: the benchmark's document as the validation report a lab
files (HTML and PDF, with the JSON it was written from).

The report is a `pipelines.reports.render.Certificate` (its sections, tables and paragraphs),
so its HTML is `render_html`'s and its PDF is set by Typst from the certificate's template
(`pipelines.reports.typeset`): one layout for every document the lab issues. The JSON beside
it holds every figure, so a later version's report compares with this one number by number.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pipelines.reports.render import Certificate, Section, render_html
from pipelines.reports.typeset import render_pdf


def _fmt(x: float | None, digits: int = 3) -> str:
    return "-" if x is None else f"{x:.{digits}g}"


def _summary(doc: Mapping[str, Any]) -> Section:
    t = doc["targets"]
    rows = [
        [
            proc,
            _fmt(s["efficiency_vs_crlb"]),
            _fmt(s["efficiency_min"]),
            _fmt(s["coverage_95"]),
            str(s["replicates"]),
            "yes" if s["meets_targets"] else "no",
        ]
        for proc, s in doc["procedures"].items()
    ]
    low, high = t["coverage_95"]
    return Section(
        "Summary per procedure",
        header=[
            "procedure",
            "efficiency (median)",
            "efficiency (lowest)",
            "coverage 95 %",
            "replicates",
            "meets targets",
        ],  # fmt: skip
        rows=rows,
        paragraphs=[
            f"Targets: efficiency against the Cramer-Rao bound >= {t['efficiency_vs_crlb_min']}"
            f" (median over the parameters), coverage of the stated U between {low} and {high}"
            f" over at least {t['replicates_min']} simulated runs per procedure."
        ],
    )


def _case(case: Mapping[str, Any]) -> Section:
    rows = [
        [
            p["name"],
            _fmt(p["rms_error"]),
            _fmt(p["mean_error"]),
            _fmt(p["bias_z"], 2),
            _fmt(p["std"]),
            _fmt(p["crlb_std"]),
            _fmt(p["efficiency"]),
            _fmt(p["coverage"]),
            _fmt(p["mean_u_ratio"]),
        ]
        for p in case["parameters"]
    ]
    s = case["summary"]
    paragraphs = [
        *([f"Condition: {case['condition']}."] if case.get("condition") else []),
        f"{case['replicates']} replicates, {case['seconds']} s. Median efficiency"
        f" {_fmt(s['efficiency_vs_crlb'])}, lowest {_fmt(s['efficiency_min'])}"
        f" ({s['efficiency_min_parameter'] or '-'}); coverage {_fmt(s['coverage_95'])}"
        f" (parameters from {_fmt(s['coverage_min'])} to {_fmt(s['coverage_max'])}).",
    ]
    unbounded = [
        p["name"] for p in case["parameters"] if p["crlb_std"] is None and ".noise" not in p["name"]
    ]
    if unbounded and not case.get("condition"):
        paragraphs.append(
            "No Cramer-Rao bound is derived for these (scored by error and coverage only; see"
            " docs/validation.md): " + ", ".join(unbounded)
        )
    if case["not_scored"]:
        paragraphs.append(
            "Reported without a stated uncertainty or a simulated truth, not scored: "
            + ", ".join(case["not_scored"])
        )
    return Section(
        f"Case {case['id']} ({case['procedure']})",
        header=[
            "parameter",
            "RMS error",
            "mean error",
            "bias z",
            "std",
            "CRLB std",
            "efficiency",
            "coverage",
            "u / std",
        ],  # fmt: skip
        rows=rows,
        paragraphs=paragraphs,
    )


def _session(s: Mapping[str, Any]) -> Section:
    title = f"Public session {s['id']} ({s['procedure']})"
    if s["status"] != "compared":
        return Section(title, paragraphs=[f"{s['status']}: {s['reason']}.", s["source"]])
    rows = [
        [
            r["parameter"],
            _fmt(r["ours"], 4),
            _fmt(r["reference"], 4),
            _fmt(r["difference"], 3),
            _fmt(r["U"], 3),
            _fmt(r["tolerance"], 3) if r["tolerance"] is not None else f"E_n {_fmt(r['e_n'], 2)}",
            "yes" if r["within_tolerance"] else "no",
        ]
        for r in s["parameters"]
    ]
    return Section(
        title,
        header=[
            "parameter",
            "ours",
            "reference",
            "difference",
            "U (ours)",
            "tolerance or E_n",
            "within",
        ],  # fmt: skip
        rows=rows,
        paragraphs=[s["source"]],
    )


def _peers(doc: Mapping[str, Any]) -> Section:
    """Per procedure and peer: E_n against ours on the first replicates, and which tool is
    nearer the truth; a peer that does not treat the procedure, with why."""
    rows = []
    for row in doc["peers"].values():
        if row["status"] != "compared":
            rows.append([row["procedure"], row["peer"], row["status"], "-", "-", "-", "-"])
            continue
        closer = f"{row['ours_closer']} of {row['with_truth']}" if row["with_truth"] else "-"
        rows.append(
            [
                row["procedure"],
                f"{row['peer']} {row['version']}",
                str(row["replicates"]),
                str(row["parameters"]),
                _fmt(row["e_n_within_1"]),
                f"{_fmt(row['e_n_max'])} ({row['e_n_max_parameter']})",
                closer,
            ]
        )
    reasons = sorted(
        {f"{r['peer']}, {r['procedure']}: {r['reason']}." for r in doc["peers"].values()
         if r["status"] != "compared"}
    )  # fmt: skip
    return Section(
        "Comparison with peer implementations",
        header=[
            "procedure",
            "peer",
            "replicates",
            "parameters",
            "E_n <= 1 (fraction)",
            "largest E_n",
            "ours nearer the truth",
        ],  # fmt: skip
        rows=rows,
        paragraphs=[
            "Each installed peer solves the raw samples of a case's first replicates as"
            " `calib validate RUN --with ...` does on an archived run; E_n = |ours - theirs|"
            " / sqrt(U_ours^2 + U_theirs^2), k = 2 (a peer that states no uncertainty counts"
            " 0). 'ours nearer the truth': parameters whose RMS error over those replicates"
            " is the smaller of the two, of those whose truth the simulation knows.",
            *reasons,
        ],
    )


def _conditions(doc: Mapping[str, Any]) -> Section:
    """The cases that stress a condition beyond the procedure's model, by their coverage."""
    rows = [
        [c["id"], c["procedure"], c["condition"], _fmt(c["coverage_95"]),
         f"{_fmt(c['coverage_min'])} ({c['coverage_min_parameter']})", str(c["replicates"])]
        for c in doc["conditions"]
    ]  # fmt: skip
    return Section(
        "Conditions beyond the model",
        header=["case", "procedure", "condition", "coverage 95 %", "lowest", "replicates"],
        rows=rows,
        paragraphs=[
            "A truth that moves within the run is outside the procedure's model, so no"
            " efficiency: such a case is judged by whether the stated U still covers the"
            " truth (its value at mid-run). It is not pooled into the procedures' figures."
        ],
    )


def report(doc: Mapping[str, Any]) -> Certificate:
    """The benchmark's document as the report's sections."""
    sw = doc["software"]
    about = Section(
        "Benchmark and software",
        pairs=[
            ("benchmark set", f"{doc['set']['name']}, version {doc['set']['version']}"),
            ("set", "reduced (quick check)" if doc["reduced"] else "full"),
            ("software", f"imu-calib {sw['version']}"),
            ("source revision", sw["revision"] or "not a git checkout"),
            ("run time", f"{doc['seconds']} s"),
        ],
        paragraphs=[
            "Each case simulates runs of one procedure with known truth (white noise, spikes or a "
            "drift of the biases where the case says) and solves them as the pipeline does "
            "(preprocessing chain, solve, Type A budget: no reference equipment is simulated). "
            "Errors are estimate - truth, SI units. Efficiency = Cramer-Rao variance / observed "
            "variance of the estimates over the replicates; coverage = fraction of replicates with "
            "|error| <= U (k from the degrees of freedom, about 95 %); u / std = mean stated "
            "standard uncertainty over the observed scatter; bias z = mean error over its standard "
            "error. Method: docs/validation.md."
        ],
    )
    sessions = [_session(s) for s in doc["sessions"]]
    sections = [about, _summary(doc), _conditions(doc), *sessions, _peers(doc)]
    sections += [_case(c) for c in doc["cases"]]
    verdict = "pass" if all(s["meets_targets"] for s in doc["procedures"].values()) else "fail"
    title = "Method validation: ground-truth benchmark"
    ident = f"benchmark {doc['set']['version']} / imu-calib {sw['version']}"
    return Certificate(title, verdict, sections, {}, "", identifier=ident)


def write_report(doc: Mapping[str, Any], folder: Path) -> dict[str, Path]:
    """Write benchmark.json, benchmark.html and benchmark.pdf into `folder` (made if absent).

    Returns kind -> path.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cert = report(doc)
    paths = {k: folder / f"benchmark.{k}" for k in ("json", "html", "pdf")}
    paths["json"].write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    paths["html"].write_text(render_html(cert), encoding="utf-8")
    render_pdf(cert, paths["pdf"])
    return paths
