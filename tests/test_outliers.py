"""Outlier detectors against injected spikes with known positions (truth)."""

import math

import numpy as np
import pytest

from calib_core.preprocess.chain import preprocess, replaced_checks
from calib_core.preprocess.outliers import (
    detect_outliers,
    false_alarm_rate,
    grubbs_critical,
    remove_outliers,
    sigma_mask,
)
from calib_core.recording import Recording
from calib_core.simulate.table import inject_spikes

N = 200_000  # samples per seed: 1000 spikes and ~100 expected false alarms per seed
SEEDS = (0, 1, 2)

# Settings and why their false-positive rate on Gaussian noise is < 0.1 %:
# sigma 3.5: 2 Q(3.5) = 0.047 %; Grubbs alpha 0.05 in blocks of 100: about
# alpha / 100 = 0.05 % per sample; Hampel 4: 2 Q(4) = 0.006 %, raised by the
# 8 % scatter of a 201-sample MAD to ~0.03 %. (3-sigma itself flags 0.27 %.)
CASES = [
    ("sigma", {"n_sigma": 3.5}),
    ("grubbs", {"alpha": 0.05, "window": 100}),
    ("hampel", {"n_sigma": 4.0, "window": 201}),
]


@pytest.mark.parametrize(("method", "kw"), CASES)
def test_detects_six_sigma_spikes_with_few_false_alarms(method, kw):
    found = injected = false = clean = 0
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        x = 9.81 + rng.normal(0.0, 0.02, N)  # a static accelerometer channel
        y, truth = inject_spikes(x, 0.005, 0.02, (6.0, 12.0), rng)
        flagged = detect_outliers(y, method, **kw)
        found += np.sum(flagged & truth)
        injected += truth.sum()
        false += np.sum(flagged & ~truth)
        clean += np.sum(~truth)
    # 3000 spikes: the binomial std of the detection rate near 99.8 % is 0.08 %;
    # 597 000 clean samples: the std of a 0.05 % false-alarm rate is 0.003 %.
    assert found / injected >= 0.99, f"{method}: detected {found}/{injected}"
    assert false / clean < 1e-3, f"{method}: {false} false positives in {clean}"


def test_three_sigma_false_alarm_rate_matches_theory():
    # On clean Gaussian noise the first pass of 3-sigma flags 2 Q(3) = 0.270 %;
    # iterating can only add samples (the std shrinks). N = 1e6: std 0.005 %.
    x = np.random.default_rng(5).normal(size=1_000_000)
    rate = sigma_mask(x, 3.0).mean()
    assert 0.0027 - 4 * 5.2e-5 < rate < 0.0027 * 1.2


def test_grubbs_critical_value_matches_table():
    # Published two-sided Grubbs table (alpha = 0.05): n=10 -> 2.290, n=100 -> 3.384.
    assert grubbs_critical(10, 0.05) == pytest.approx(2.290, abs=2e-3)
    assert grubbs_critical(100, 0.05) == pytest.approx(3.384, abs=2e-3)


def _static_recording(seed, n=20_000):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.02, (n, 3))
    gyr = rng.normal(0.0, 1e-3, (n, 3))
    return Recording(t=t, acc=acc, gyr=gyr, source="static.csv")


def test_interpolate_policy_restores_the_clean_signal():
    rec = _static_recording(3)
    acc, mask = inject_spikes(rec.acc, 0.005, 0.02, (6.0, 12.0), np.random.default_rng(4))
    spiked = Recording(t=rec.t, acc=acc, gyr=rec.gyr, source=rec.source)
    out, record = remove_outliers(spiked, "hampel", n_sigma=4.0)
    assert len(out) == len(rec)
    # A replaced value interpolates two noisy neighbours: error std about 0.02
    # around the constant truth; 6 std bounds every one of ~300 replacements.
    truth = np.broadcast_to([0.0, 0.0, 9.81], acc.shape)
    assert np.max(np.abs(out.acc[mask] - truth[mask])) < 6 * 0.02
    assert record.statistics["n_flagged"]["acc.x"] >= mask[:, 0].sum() * 0.99
    assert set(np.flatnonzero(mask[:, 2])) <= set(record.statistics["flagged_indices"]["acc.z"])
    # Spikes of 6..12 sigma at 0.5 % biased nothing on average (random signs) but
    # raised the std; after cleaning the std is back to the noise (std of a
    # 20000-sample std estimate: 0.5 %).
    assert out.acc[:, 2].std() == pytest.approx(0.02, rel=0.03)
    assert spiked.acc[:, 2].std() > 0.02 * 1.1


def test_delete_policy_drops_rows_and_records_them():
    rec = _static_recording(6, n=5_000)
    gyr = rec.gyr.copy()
    gyr[[100, 2000], 1] += 0.05  # 50 sigma
    spiked = Recording(t=rec.t, acc=rec.acc, gyr=gyr, source="static.csv")
    out, record = remove_outliers(spiked, "sigma", n_sigma=4.5, policy="delete", channels=("gyr",))
    assert record.statistics["flagged_indices"]["gyr.y"] == [100, 2000]
    # 2 Q(4.5) * 15000 samples = 0.1 expected false alarms; allow none beyond 1.
    assert len(rec) - 3 <= len(out) <= len(rec) - 2
    assert 100 / 100.0 not in set(out.t) and 2000 / 100.0 not in set(out.t)
    assert record.settings["policy"] == "delete"


def test_bad_settings_name_the_source():
    rec = _static_recording(0, n=100)
    with pytest.raises(ValueError, match=r"static\.csv.*unknown method"):
        remove_outliers(rec, "median")
    with pytest.raises(ValueError, match="unknown policy"):
        remove_outliers(rec, policy="clip")


def _plain_sigma_clip(x, n_sigma, max_iter=20):
    """Reference: the textbook loop over all samples every pass (independent of the
    candidate-set shortcut in sigma_mask)."""
    flagged = np.zeros(x.size, dtype=bool)
    for _ in range(max_iter):
        good = x[~flagged]
        if good.size < 3:
            break
        new = flagged | (np.abs(x - good.mean()) > n_sigma * good.std(ddof=1))
        if np.array_equal(new, flagged):
            break
        flagged = new
    return flagged


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_sigma_mask_equals_plain_clipping_on_every_column(seed):
    rng = np.random.default_rng(seed)
    # Gaussian and heavy-tailed columns with spikes, one near-constant column
    # (large mean, tiny noise: tests the centring) and a tiny one (n < 3 rule).
    x = np.column_stack(
        [
            rng.normal(9.81, 0.02, 5000),
            rng.standard_t(3, 5000),
            1e4 + rng.normal(0.0, 1e-6, 5000),
        ]
    )
    x[rng.choice(5000, 50, replace=False), 0] += 0.3
    got = sigma_mask(x, 3.0)
    for j in range(x.shape[1]):
        np.testing.assert_array_equal(got[:, j], _plain_sigma_clip(x[:, j], 3.0))
    assert got[:, 0].sum() >= 50  # the spikes are 15 sigma: all found
    assert not sigma_mask(np.array([1.0, 5.0]), 3.0).any()


def test_interpolated_runs_match_numpy_interp_including_the_edges():
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.5, 1.5, 400))  # uneven spacing
    acc = rng.normal(0.0, 1.0, (400, 3))
    acc[[0, 1, 50, 51, 52, 200, 398, 399], 0] += 100.0  # runs, including both ends
    before = acc.copy()
    rec = Recording(t=t, acc=acc, gyr=np.zeros((400, 3)), source="runs.csv")
    out, record = remove_outliers(rec, "sigma", n_sigma=5.0, channels=("acc",))
    bad = np.array(record.statistics["flagged_indices"]["acc.x"])
    assert set(bad) >= {0, 1, 50, 51, 52, 200, 398, 399}
    good = np.setdiff1d(np.arange(400), bad)
    # np.interp holds the edge values beyond the first / last good sample, as documented.
    expected = np.interp(t[bad], t[good], acc[good, 0])
    np.testing.assert_allclose(out.acc[bad, 0], expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(out.acc[good], acc[good])
    np.testing.assert_array_equal(rec.acc, before)  # the input is not modified


@pytest.mark.parametrize(
    ("method", "kw"),
    [
        ("sigma", {"n_sigma": 3.0}),
        ("sigma", {"n_sigma": 3.5}),
        ("hampel", {"n_sigma": 3.0, "window": 201}),
        ("grubbs", {"alpha": 0.05, "window": 100}),
    ],
)
def test_false_alarm_rate_is_what_clean_noise_gives(method, kw):
    """The rate each step's check is judged by: on clean Gaussian noise (3 x 200,000
    samples) the flagged count is within 5 binomial stds of N p."""
    n = 3 * N
    x = np.random.default_rng(17).standard_normal(n)
    p = false_alarm_rate(method, kw.get("n_sigma", 3.0), kw.get("alpha", 0.05), kw.get("window"))
    flagged = int(detect_outliers(x, method, **kw).sum())
    assert abs(flagged - n * p) < 5 * math.sqrt(n * p * (1 - p)), (flagged, n * p)


def _statics(seed: int) -> dict[str, Recording]:
    rng = np.random.default_rng(seed)
    n = 6000
    return {
        label: Recording(
            np.arange(n) / 100.0,
            0.02 * rng.standard_normal((n, 3)) + [0, 0, 9.81],
            0.001 * rng.standard_normal((n, 3)),
            source=f"{label}.csv",
        )
        for label in ("x_up", "x_dn")
    }


def test_outlier_step_counts_and_checks_what_it_altered():
    """The default outlier step (3-sigma, interpolate) on clean statics: its counts per
    segment and channel are in the step record, and its checks pass (the count is what
    false alarms explain). With 1 % spikes of 6-12 stds in one channel of x_dn, that
    segment's check fails with the channel's count; x_up's still passes."""
    segments = _statics(3)
    _, steps = preprocess(segments, {})
    checks = {c["name"]: c for c in replaced_checks(steps)}
    assert set(checks) == {"model:replaced:outliers:x_up", "model:replaced:outliers:x_dn"}
    assert all(c["passed"] for c in checks.values()), checks
    per_segment = steps[0].statistics["segments"]
    for label, c in checks.items():
        assert c["value"] == sum(per_segment[label.rsplit(":", 1)[1]]["n_flagged"].values())
    rec = segments["x_dn"]
    acc, _ = inject_spikes(rec.acc[:, :1], 0.01, 0.02, rng=np.random.default_rng(4))
    spiked = np.column_stack([acc, rec.acc[:, 1:]])
    segments["x_dn"] = Recording(rec.t, spiked, rec.gyr, source=rec.source)
    _, steps = preprocess(segments, {})
    checks = {c["name"]: c for c in replaced_checks(steps)}
    assert checks["model:replaced:outliers:x_up"]["passed"]
    bad = checks["model:replaced:outliers:x_dn"]
    assert not bad["passed"] and bad["value"] > bad["limit"]
    assert "acc.x " in bad["detail"] and "interpolated" in bad["detail"]
