"""The ground-truth benchmark: the Cramer-Rao bound of a design, the scores against it, and
benchmarks/validation_set.py on the reduced set (its JSON, its report read back as HTML words
and PDF text)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calib_core import crlb
from calib_testing.documents import html_words, pdf_pages
from pipelines.validation import benchmark
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
    with pytest.raises(ValueError, match=r"set\.json: cases\[0\] \(\?\) has no 'id'"):
        benchmark.load_set(path)
    path.write_text("{")
    with pytest.raises(ValueError, match="set.json: cannot read"):
        benchmark.load_set(path)


@pytest.fixture(scope="module")
def reduced(tmp_path_factory):
    """benchmarks/validation_set.py, the benchmark's entry, on the reduced set."""
    out = tmp_path_factory.mktemp("benchmark")
    script = ROOT / "benchmarks" / "validation_set.py"
    args = [sys.executable, str(script), "--reduced", "--workers", "1", "--out", str(out)]
    res = subprocess.run(args, capture_output=True, text=True, timeout=900, check=False)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1]), out


@pytest.mark.slow  # 30 simulated replicates of every procedure; fast: test_procedures, one each
def test_reduced_benchmark_prints_each_procedure(reduced):
    doc, _ = reduced
    cases = benchmark.load_set()["cases"]
    assert set(doc["procedures"]) == {c["procedure"] for c in cases if c["reduced_replicates"]}
    assert doc["set"]["version"] == benchmark.load_set()["version"] and doc["reduced"] is True
    assert [s["status"] for s in doc["sessions"]] == ["not run"]  # no --realdata given
    for proc, s in doc["procedures"].items():
        assert 0.0 <= s["coverage_95"] <= 1.0, proc
        assert s["replicates"] == 30 and s["meets_targets"] is False  # 30 < 200 replicates
    # The procedures whose estimators are efficient (docs/validation.md): the median over
    # >= 9 parameters of an efficiency with relative standard error sqrt(2/29) = 0.26 each
    # stays within 4 of its standard errors (about 0.11) of 1.
    for proc in ("six_position", "multi_position", "rate_table", "static_bias"):
        assert doc["procedures"][proc]["efficiency_vs_crlb"] > 0.55, (proc, doc["procedures"])


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


REALDATA = ROOT.parent / "shared" / "realdata"


def test_public_session_against_its_datasheet(tmp_path):
    """imu_tk's Xsens session, processed as a lab run (ingest, preprocessing, equipment-free
    solve) against the datasheet: every bias and scale within the datasheet's own stability
    figures; a data folder without the files says which and where."""
    set_doc = benchmark.load_set()
    missing = run_sessions(set_doc, tmp_path)
    assert [s["status"] for s in missing] == ["not found"]
    assert str(tmp_path / "imutk_xsens") in missing[0]["reason"]
    assert "xsens_acc.mat" in missing[0]["reason"]
    if not (REALDATA / "imutk_xsens").is_dir():
        pytest.skip(f"real data not found at {REALDATA} (the shared realdata folder is absent)")
    (xsens,) = run_sessions(set_doc, REALDATA)
    assert xsens["status"] == "compared"
    assert {r["parameter"] for r in xsens["parameters"]} == set(set_doc["sessions"][0]["reference"])
    assert all(r["within_tolerance"] for r in xsens["parameters"]), xsens["parameters"]
