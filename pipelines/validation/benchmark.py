"""Ground-truth benchmark, the pipeline glue: the versioned set (benchmark_set.json) run on
the installed software and scored (`calib validate --benchmark`, docs/validation.md).

Each simulated case is solved as a lab runs it: the preprocessing chain, the procedure's
solve and its budget (no equipment stated: Type A, k from its degrees of freedom). Its
replicates share truth and design and differ in noise only, drawn from the case's seed and
the replicate's index, so a result does not depend on the order, the worker or the machine.
The Cramer-Rao bound of each case is computed once from its noise-free model
(`calib_core.crlb`). The result is one JSON-able document (`run_benchmark`); the report
(HTML and PDF) is written from it by `pipelines.validation.benchmark_report`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from calib_core import crlb, procedures
from calib_core.preprocess.chain import preprocess
from calib_core.run_budget import run_budgets
from calib_core.settings import Setting, SettingError, Settings, checked, refusal
from pipelines.provenance import SOFTWARE_VERSION, source_revision
from pipelines.validation.benchmark_peers import PeerTally

SET_FILE = Path(__file__).with_name("benchmark_set.json")


# What `load_set` checks of the set file (a JSON object) and of each of its cases, the keys
# the runner reads; others (description, a case's segments and simulation) are the design's.
BENCHMARK_SET = Settings(
    Setting("name", "text", "", None, "the set's name"),
    Setting("version", ("text", "integer"), "", None, "the set's version"),
    Setting("cases", "list", "", None, "the simulated cases (BENCHMARK_CASE)"),
    Setting("targets", "table", "", None, "the scores each case must reach"),
    name="BenchmarkSet",
    noun="field",
)
BENCHMARK_CASE = Settings(
    Setting("id", "text", "", None, "the case's name"),
    Setting("procedure", "text", "", None, "the procedure solved (calib_core.procedures)"),
    Setting("simulator", "text", "", None, "the design's simulator"),
    Setting("truth", "table", "", None, "the true parameters"),
    Setting("replicates", "integer", "", None, "replicates scored", low=1),
    Setting("seed", "integer", "", None, "the seed of its replicates' noise", low=0),
    name="BenchmarkCase",
    noun="field",
)


def load_set(path: Path = SET_FILE) -> dict[str, Any]:
    """The benchmark set's definition (JSON), checked for what the runner reads
    (`BENCHMARK_SET`, each case a `BENCHMARK_CASE` of a known procedure).

    Raises ValueError naming the file, the dotted key (a JSON file: its key path, no
    line), what was expected and what was found (calib_core.settings.refusal).
    """
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"benchmark set {path}: cannot read it: {exc}") from None
    try:
        checked(BENCHMARK_SET, doc, "", tuple(BENCHMARK_SET.items), others=True)
        for i, case in enumerate(doc["cases"]):
            checked(BENCHMARK_CASE, case, f"cases[{i}]", tuple(BENCHMARK_CASE.items), others=True)
            try:
                procedures.get(case["procedure"])
            except ValueError as exc:  # naming the known ones
                raise SettingError("procedure", str(exc), f"cases[{i}]") from None
    except SettingError as exc:
        raise refusal("benchmark set", path, None, exc) from None
    return doc


def _replicate(
    design: Any, procedure: str, seed: int, index: int, tally: PeerTally | None = None
) -> dict[str, tuple]:
    """One replicate solved as the pipeline solves a run: name -> (estimate, u, U); the
    peers of `tally` given its raw segments and our solution."""
    rng = np.random.default_rng([seed, index])
    raw = design.draw(design.theta, rng)
    segments, _ = preprocess(raw, design.settings, design.gravity)
    cal = procedures.solve(procedure, segments, design.gravity, dict(design.settings))
    budgets = run_budgets(cal, segments, design.settings, None)
    if tally is not None:
        tally.add(raw, cal)
    return {n: (p.value, p.std, budgets[n].U) for n, p in cal.parameters.items() if n in budgets}


# A case of the set -> its design with known truth (calib_testing.benchmark_cases.design).
DesignOf = Callable[[Mapping[str, Any]], Any]


def run_case(
    case: Mapping[str, Any], replicates: int, make_design: DesignOf, peer_replicates: int = 0
) -> dict[str, Any]:
    """Score one simulated case over `replicates` replicates of `make_design(case)`; the
    installed peers on the first `peer_replicates` of them (`benchmark_peers`).

    Returns the case's document: id, procedure, the condition it stresses (None: the
    procedure's model holds), replicates, per parameter scores
    (`calib_core.crlb.ParameterScore`; no efficiency where the bound is not derived or the
    case is a condition's), the summary and the seconds taken.
    """
    start = time.perf_counter()
    design = make_design(case)
    bound: dict[str, float] = {}
    # a case beyond the model is judged by coverage alone; a design without a model has
    # no bound derived
    if design.condition is None and design.model is not None:
        model_theta = design.theta if design.bounded is None else design.bounded
        names, info = crlb.fisher_information(
            design.model, model_theta, design.steps, linear=design.linear
        )
        bound = dict(zip(names, crlb.crlb_variances(info), strict=True))
    truth = {**design.theta, **design.noise}
    tally = PeerTally(case["procedure"], design.gravity, design.settings, truth)
    n_peer = min(peer_replicates, replicates) if design.condition is None else 0
    runs = [
        _replicate(design, case["procedure"], int(case["seed"]), i, tally if i < n_peer else None)
        for i in range(replicates)
    ]
    # a term a procedure keeps in some replicates only (chosen by a test) is not scored
    kept = set.intersection(*(set(r) for r in runs)) if runs else set()
    scored = [n for n in runs[0] if n in truth and n in kept] if runs else []
    scores = []
    for name in scored:
        est, u, big_u = (np.array([r[name][k] for r in runs], float) for k in range(3))
        scores.append(crlb.score_parameter(name, est, truth[name], u, big_u, bound.get(name)))
    unscored = sorted(set().union(*runs) - set(scored)) if runs else []
    return {
        "id": case["id"],
        "procedure": case["procedure"],
        "simulator": case["simulator"],
        "condition": design.condition,
        "replicates": replicates,
        "summary": crlb.summarise(scores),
        "parameters": [s.to_dict() for s in scores],
        "not_scored": unscored,
        "peers": tally.result() if n_peer else [],
        "seconds": round(time.perf_counter() - start, 2),
    }


def _run_one(args: tuple[dict[str, Any], int, DesignOf, int]) -> dict[str, Any]:
    return run_case(*args)


def run_benchmark(
    set_doc: Mapping[str, Any],
    make_design: DesignOf,
    *,
    reduced: bool = False,
    workers: int = 1,
    progress: Callable[[str], None] | None = None,
    realdata: Path | None = None,
) -> dict[str, Any]:
    """Run every simulated case of the set; the benchmark's document.

    Parameters
    ----------
    set_doc : the set (`load_set`).
    make_design : a case -> its design with known truth, noisy draws and noise-free model
        (calib_testing.benchmark_cases.design; a module-level function, so that worker
        processes receive it).
    reduced : each case's `reduced_replicates` (a case with 0 is left out) in place of
        its `replicates`: the quick set of the tests.
    workers : processes the cases are spread over (1: this process).
    progress : called with a line per finished case.
    realdata : the folder of the public recordings (`sessions` of the set); None: the
        sessions are listed as not run.
    """
    from pipelines.validation.benchmark_sessions import run_sessions

    start = time.perf_counter()
    jobs = []
    for case in set_doc["cases"]:
        n = int(case.get("reduced_replicates", 0) if reduced else case["replicates"])
        n_peer = int(set_doc.get("peer_replicates", {}).get("reduced" if reduced else "full", 0))
        if n > 0:
            jobs.append((dict(case), n, make_design, n_peer))
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            cases = list(pool.map(_run_one, jobs))
    else:
        cases = [_run_one(job) for job in jobs]
    for c in cases:
        if progress:
            progress(f"{c['id']}: {c['replicates']} replicates, {c['seconds']} s")
    return {
        "set": {"name": set_doc["name"], "version": set_doc["version"]},
        "software": {"version": SOFTWARE_VERSION, "revision": source_revision()},
        "reduced": reduced,
        "targets": set_doc["targets"],
        "cases": cases,
        "procedures": by_procedure(cases, set_doc["targets"]),
        "conditions": conditions(cases),
        "sessions": run_sessions(set_doc, realdata),
        "peers": by_peer(cases),
        "seconds": round(time.perf_counter() - start, 2),
    }


def run_and_report(
    cases: str | None,
    *,
    set_file: Path | None = None,
    reduced: bool = False,
    workers: int = 1,
    out: Path | None = None,
    realdata: Path | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """`calib validate --benchmark`: the set run with the cases' provider, the report written.

    Parameters
    ----------
    cases : `--cases` MODULE[:NAME], or None for the entry point group's provider
        (`pipelines.validation.cases`).
    set_file : a set in place of the versioned one (`SET_FILE`).
    out : folder of the report (benchmark.json, .html, .pdf); None: not written.
    Others as `run_benchmark`.

    Returns the benchmark's document without its cases' tables, with `cases_provider` and
    `report` (kind -> path written). Raises `cases.NoProviderError` or ValueError (a bad set).
    """
    from pipelines.validation import cases as providers
    from pipelines.validation.benchmark_report import write_report

    provider_name, make_design = providers.find_provider(cases)
    set_doc = load_set(set_file) if set_file else load_set()
    doc = run_benchmark(
        set_doc, make_design, reduced=reduced, workers=workers, progress=progress, realdata=realdata
    )
    written = write_report(doc, out) if out else {}
    summary = {k: v for k, v in doc.items() if k != "cases"}
    paths = {k: str(v) for k, v in written.items()}
    return {**summary, "cases_provider": provider_name, "report": paths}


def by_peer(cases: list[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per procedure and installed peer (`benchmark_peers`): whether it treats the procedure
    (or why not), the replicates compared, the fraction of its parameters' E_n <= 1, the
    largest E_n and which parameter, and on how many parameters with a known truth our
    RMS error is the smaller. Cases of a condition are not given to the peers."""
    out: dict[str, dict[str, Any]] = {}
    for c in cases:
        for p in c.get("peers", []):
            key = f"{c['procedure']} / {p['peer']}"
            row = out.setdefault(
                key,
                {"procedure": c["procedure"], "peer": p["peer"], "version": p["version"],
                 "status": p["status"], "reason": p["reason"], "cases": [], "replicates": 0,
                 "parameters": 0, "e_n_within_1": None, "e_n_max": None,
                 "e_n_max_parameter": None, "ours_closer": 0, "with_truth": 0},
            )  # fmt: skip
            if p["status"] != "compared":
                continue
            row |= {"status": "compared", "reason": None}
            row["cases"].append(c["id"])
            row["replicates"] += p["replicates"]
            params = p["parameters"]
            within = [q["e_n_within_1"] for q in params if q["e_n_within_1"] is not None]
            done = row["parameters"] * (row["e_n_within_1"] or 0.0)
            row["parameters"] += len(params)
            row["e_n_within_1"] = (done + sum(within)) / row["parameters"] if params else None
            if p.get("e_n_max") is not None and p["e_n_max"] > (row["e_n_max"] or -1.0):
                row["e_n_max"], row["e_n_max_parameter"] = p["e_n_max"], p["e_n_max_parameter"]
            known = [q for q in params if q["rms_error_theirs"] is not None]
            row["with_truth"] += len(known)
            row["ours_closer"] += sum(q["rms_error_ours"] < q["rms_error_theirs"] for q in known)
    return out


def by_procedure(
    cases: list[Mapping[str, Any]], targets: Mapping[str, Any]
) -> dict[str, dict[str, Any]]:
    """Per procedure: the median efficiency and the pooled coverage over its cases'
    parameters, the replicates behind them and whether they meet the set's targets (the
    `--json` summary). The cases of a condition (a drifting truth) are left out: they
    are shown by `conditions`."""
    out: dict[str, dict[str, Any]] = {}
    cases = [c for c in cases if c.get("condition") is None]  # conditions: their own table
    for proc in dict.fromkeys(c["procedure"] for c in cases):
        params = [p for c in cases if c["procedure"] == proc for p in c["parameters"]]
        effs = [p["efficiency"] for p in params if p["efficiency"] is not None]
        out[proc] = {
            "efficiency_vs_crlb": float(np.median(effs)) if effs else None,
            "efficiency_min": min(effs) if effs else None,
            "coverage_95": float(np.mean([p["coverage"] for p in params])) if params else None,
            "replicates": min(c["replicates"] for c in cases if c["procedure"] == proc),
            "cases": [c["id"] for c in cases if c["procedure"] == proc],
        }
        out[proc]["meets_targets"] = meets(out[proc], targets)
    return out


def conditions(cases: list[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The cases that stress a condition beyond the procedure's model: per case its
    pooled coverage, the lowest parameter's and the stated u over the observed scatter."""
    out = []
    for c in cases:
        if c.get("condition") is None:
            continue
        low = min(c["parameters"], key=lambda p: p["coverage"])
        out.append(
            {
                "id": c["id"],
                "procedure": c["procedure"],
                "condition": c["condition"],
                "coverage_95": c["summary"]["coverage_95"],
                "coverage_min": low["coverage"],
                "coverage_min_parameter": low["name"],
                "replicates": c["replicates"],
            }
        )
    return out


def meets(summary: Mapping[str, Any], targets: Mapping[str, Any]) -> bool:
    """Whether a procedure's figures meet the set's targets (efficiency, coverage band,
    replicates)."""
    eff, cov = summary["efficiency_vs_crlb"], summary["coverage_95"]
    low, high = targets["coverage_95"]
    return (
        (eff is None or eff >= targets["efficiency_vs_crlb_min"])
        and cov is not None
        and low <= cov <= high
        and summary["replicates"] >= targets["replicates_min"]
    )
