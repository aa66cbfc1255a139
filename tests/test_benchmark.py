"""The ground-truth benchmark: the Cramer-Rao bound of a design, the scores against it, and
`calib validate --benchmark` on the reduced set (its JSON, its report read back as HTML words
and PDF text); the cases' provider found at run time, or the command saying what to do."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calib_core import crlb
from calib_testing import benchmark_cases
from calib_testing.documents import html_words, pdf_pages
from pipelines.validation import benchmark, cases
from pipelines.validation.benchmark_sessions import run_sessions

ROOT = Path(__file__).resolve().parents[1]
SIGMA = 0.3


def _mean_model(n: int):
    def model(theta):
        return [(np.full((n, 1), theta["b"]), np.array([SIGMA]), None)]

    return model


def test_bound_of_a_mean_is_sigma2_over_n():
    names, info = crlb.fisher_information(_mean_model(400), {"b": 1.5}, {"b": 1e-6})
    assert names == ["b"]
    assert crlb.crlb_variances(info)[0] == pytest.approx(SIGMA**2 / 400, rel=1e-6)


def test_an_unknown_profile_leaves_only_its_known_sum():
    """y_t = s w_t + noise with w_t unknown at each sample but for sum(w) (a turn's angle):
    the only information on s is that sum, CRLB = N sigma^2 / sum(w)^2, as the estimator
    sum(y) / sum(w) attains; with w known it would be sigma^2 / sum(w^2)."""
    w = np.sin(np.linspace(0.0, np.pi, 200)) ** 2

    def model(theta, nuisance=True):
        d = np.full((w.size, 1), theta["s"]) if nuisance else None
        return [((theta["s"] * w)[:, None], np.array([SIGMA]), d)]

    _, info = crlb.fisher_information(model, {"s": 1.01}, {"s": 1e-6})
    assert crlb.crlb_variances(info)[0] == pytest.approx(w.size * SIGMA**2 / w.sum() ** 2)
    _, known = crlb.fisher_information(lambda t: model(t, False), {"s": 1.01}, {"s": 1e-6})
    assert crlb.crlb_variances(known)[0] == pytest.approx(SIGMA**2 / (w**2).sum())


def test_an_unidentifiable_direction_does_not_shrink_the_others():
    """b1 and b2 seen only as their sum: no bound on either (null direction of I), and a
    third parameter seen alone keeps its own bound."""

    def model(theta):
        one = np.full((100, 1), theta["b1"] + theta["b2"])
        return [(one, np.array([SIGMA]), None), (np.full((50, 1), theta["c"]), [SIGMA], None)]

    _, info = crlb.fisher_information(model, {"b1": 0.1, "b2": 0.2, "c": 0.0}, dict.fromkeys(
        ("b1", "b2", "c"), 1e-6))  # fmt: skip
    var = crlb.crlb_variances(info)
    assert var[2] == pytest.approx(SIGMA**2 / 50)
    # pinv: the estimable sum's half on each, never below the bound of the sum itself
    assert var[0] == pytest.approx(SIGMA**2 / 100 / 4)


def _replicates(n_rep: int, n: int, keep: int, rng):
    """Means of the first `keep` of n samples: (estimates, u, U) per replicate."""
    x = rng.normal(0.0, SIGMA, (n_rep, n))[:, :keep]
    est = x.mean(axis=1)
    u = x.std(axis=1, ddof=1) / math.sqrt(keep)
    return est, u, 1.96 * u


def test_scores_see_an_efficient_and_a_wasteful_estimator():
    """The mean of all samples is efficient (efficiency 1 within sqrt(2/(n-1)), 4 standard
    errors); the mean of half of them has efficiency 1/2. Coverage of U = 1.96 u within 4
    binomial standard errors of 0.95."""
    rng = np.random.default_rng(7)
    n_rep, n = 400, 200
    tol = 4 * math.sqrt(2 / (n_rep - 1))
    bound = SIGMA**2 / n
    for keep, expected in ((n, 1.0), (n // 2, 0.5)):
        est, u, big_u = _replicates(n_rep, n, keep, rng)
        s = crlb.score_parameter("b", est, 0.0, u, big_u, bound)
        assert abs(s.efficiency / expected - 1) < tol, s
        assert abs(s.coverage - 0.95) < 4 * math.sqrt(0.95 * 0.05 / n_rep), s
        assert abs(s.bias_z) < 4
    # an uncertainty stated too small shows as low coverage and u / std < 1
    est, u, _ = _replicates(n_rep, n, n, rng)
    s = crlb.score_parameter("b", est, 0.0, u / 2, 1.96 * u / 2, bound)
    assert s.coverage < 0.8 and s.mean_u_ratio == pytest.approx(0.5, rel=tol)


def test_a_bad_set_names_file_and_field(tmp_path):
    path = tmp_path / "set.json"
    path.write_text(json.dumps({"name": "x", "version": "1", "targets": {}, "cases": [{}]}))
    with pytest.raises(ValueError, match=r"set\.json: cases\[0\]\.id: required field is missing"):
        benchmark.load_set(path)
    case = {"id": "c", "procedure": "six_position", "simulator": "s", "truth": {}, "seed": 1}
    for changed, expected in [
        ({"replicates": "2"}, r"cases\[0\]\.replicates: expected a whole number >= 1, got '2'"),
        ({"replicates": 2, "seed": float("nan")}, r"cases\[0\]\.seed: expected .*, got nan"),
        ({"replicates": 2, "procedure": "six"}, r"cases\[0\]\.procedure: unknown procedure 'six'"),
    ]:
        doc = {"name": "x", "version": "1", "targets": {}, "cases": [case | changed]}
        path.write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=f"^benchmark set {re.escape(str(path))}: {expected}"):
            benchmark.load_set(path)
    path.write_text(json.dumps({"name": "x", "version": "1", "cases": []}))
    with pytest.raises(ValueError, match="set.json: targets: required field is missing"):
        benchmark.load_set(path)
    path.write_text("{")
    with pytest.raises(ValueError, match="set.json: cannot read"):
        benchmark.load_set(path)


PROVIDER = "calib_testing.benchmark_cases"


def _calib(args: list[str], pythonpath: Path, cwd: Path) -> subprocess.CompletedProcess:
    """The CLI in its own process, with `pythonpath` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(pythonpath), "COLUMNS": "200"}
    cmd = [sys.executable, "-m", "pipelines.cli", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=900, env=env, cwd=cwd)


@pytest.fixture(scope="module")
def reduced(tmp_path_factory):
    """`calib validate --benchmark --reduced --json`, from the checkout, on the reduced set.
    The provider is named (--cases): the installed metadata's entry point is that of the
    last editable install, which need not be this tree's."""
    out = tmp_path_factory.mktemp("benchmark")
    args = ["validate", "--benchmark", "--reduced", "--json", "--out", str(out)]
    res = _calib([*args, "--cases", PROVIDER], ROOT, ROOT)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout), out


@pytest.mark.slow  # 30 simulated replicates of every procedure; fast: test_procedures, one each
def test_reduced_benchmark_prints_each_procedure(reduced):
    doc, out = reduced
    assert doc["report"] == {k: str(out / f"benchmark.{k}") for k in ("json", "html", "pdf")}
    assert doc["cases_provider"] == f"--cases = {PROVIDER}:design"
    set_doc = benchmark.load_set()
    run = [c for c in set_doc["cases"] if c["reduced_replicates"]]
    assert set(doc["procedures"]) == {c["procedure"] for c in run if "drift" not in c}
    assert doc["set"]["version"] == set_doc["version"] and doc["reduced"] is True
    assert [s["status"] for s in doc["sessions"]] == ["not run"] * len(set_doc["sessions"])
    for proc, s in doc["procedures"].items():
        assert 0.0 <= s["coverage_95"] <= 1.0, proc
        fewest = min(c["reduced_replicates"] for c in run if c["id"] in s["cases"])
        assert s["replicates"] == fewest and s["meets_targets"] is False  # < 200 replicates
    # The procedures whose estimators are efficient (docs/validation.md), 5 replicates: each
    # parameter's efficiency is 4 / chi2(4) times its true one, below 0.3 with probability
    # 0.01 and above 5 with 0.06; the median of >= 9 parameters beyond either: < 1e-3. A
    # bound off by an order of magnitude, or a wasteful estimator, fails it.
    for proc in ("six_position", "multi_position", "rate_table", "six_position_integral"):
        assert 0.3 < doc["procedures"][proc]["efficiency_vs_crlb"] < 5.0, (proc, doc)
    # the drifting truth is shown apart, judged by coverage alone
    (drift,) = doc["conditions"]
    assert drift["id"] == "six_position-drift" and "drift" in drift["condition"]
    # each installed peer compared where it treats the procedure, and says why elsewhere
    peers = doc["peers"]
    for key, row in peers.items():
        assert row["status"] in ("compared", "cannot treat", "not installed"), key
        assert (row["reason"] is None) == (row["status"] == "compared"), key
    compared = {k for k, r in peers.items() if r["status"] == "compared"}
    installed = {r["peer"] for r in peers.values() if r["status"] != "not installed"}
    expected = {"six_position_integral / imucal", "static_bias / allantools"}
    assert compared == {k for k in expected if k.split(" / ")[1] in installed}
    for key in compared:  # independent methods on the same bytes agree within U
        assert peers[key]["e_n_within_1"] >= 0.8, peers[key]


@pytest.mark.slow  # the reduced benchmark's report (the fixture above)
def test_reduced_benchmark_report_is_readable(reduced):
    doc, out = reduced
    full = json.loads((out / "benchmark.json").read_text())
    assert full["procedures"] == doc["procedures"]
    words = " ".join(html_words((out / "benchmark.html").read_text()))
    text = " ".join(pdf_pages(out / "benchmark.pdf"))
    for source in (words, text):
        assert "ground-truth benchmark" in source
        for case in full["cases"]:
            assert case["id"] in source
    eff = full["procedures"]["six_position"]["efficiency_vs_crlb"]
    assert f"{eff:.3g}" in text
    for source in (words, text):
        assert "Comparison with peer implementations" in source
        assert "Conditions beyond the model" in source and "six_position-drift" in source


def test_without_a_provider_the_command_says_what_to_do(tmp_path):
    """Outside a checkout (the product's packages alone on the path, as a wheel installs
    them) the cases cannot be found: exit 2 and where to run it; a --cases module that does
    not exist is named."""
    product = tmp_path / "site"
    product.mkdir()
    for pkg in ("calib_core", "storage", "pipelines"):
        (product / pkg).symlink_to(ROOT / pkg)
    res = _calib(["validate", "--benchmark", "--json", "--out", str(tmp_path)], product, tmp_path)
    assert res.returncode == 2, res.stdout + res.stderr
    message = " ".join(res.stderr.split())
    assert "PYTHONPATH=. calib validate --benchmark" in message, message
    assert "imu_calib.benchmark_cases" in message and res.stdout == ""
    assert not (tmp_path / "benchmark.json").exists()
    bad = _calib(["validate", "--benchmark", "--cases", "no_such_cases"], product, tmp_path)
    assert bad.returncode == 2 and "no_such_cases:design cannot be loaded" in bad.stderr


def test_the_entry_point_group_finds_a_declared_provider(tmp_path, monkeypatch):
    """A distribution declaring the group (its metadata on the path, read by
    importlib.metadata as for any installed package) is the provider without --cases."""
    dist = tmp_path / "bench_cases-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: bench-cases\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[{cases.GROUP}]\ncheckout = {PROVIDER}:design\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    name, provider = cases.find_provider(None)
    assert name == f"checkout = {PROVIDER}:design"
    assert provider is benchmark_cases.design


REALDATA = ROOT.parent / "shared" / "realdata"


def test_public_sessions_against_their_references(tmp_path):
    """The public sessions, each processed as a lab run (ingest, preprocessing, solve):
    imu_tk's Xsens session (equipment-free) with every bias and scale within the datasheet's
    own stability figures; imucal's annotated session (six_position_integral) against
    imucal's published calibration of it, every one of the 33 parameters at E_n <= 1
    (docs/validation.md: the accelerometer biases differ by method, and their uncertainty
    carries the faces' misfit). A data folder without the files says which and where."""
    set_doc = benchmark.load_set()
    missing = run_sessions(set_doc, tmp_path)
    assert [s["status"] for s in missing] == ["not found", "not found"]
    assert str(tmp_path / "imutk_xsens") in missing[0]["reason"]
    assert "xsens_acc.mat" in missing[0]["reason"]
    assert "annotated_session.csv" in missing[1]["reason"]
    if not (REALDATA / "imutk_xsens").is_dir() or not (REALDATA / "imucal_ferraris").is_dir():
        pytest.skip(f"real data not found at {REALDATA} (the shared realdata folder is absent)")
    xsens, annotated = run_sessions(set_doc, REALDATA)
    for session, ref in zip((xsens, annotated), set_doc["sessions"], strict=True):
        assert session["status"] == "compared"
        assert {r["parameter"] for r in session["parameters"]} == set(ref["reference"])
        assert all(r["within_tolerance"] for r in session["parameters"]), session["parameters"]
    assert all(r["e_n"] is None for r in xsens["parameters"])  # a datasheet states no result
    assert len(annotated["parameters"]) == 33
    assert all(r["e_n"] is not None and r["tolerance"] is None for r in annotated["parameters"])
