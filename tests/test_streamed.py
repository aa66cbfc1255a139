"""Streamed statistics (calib_core.streamed) against one pass over the whole array and
against allantools; the streamed static-bias solve against the in-memory one."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import allantools
import numpy as np
import pytest

from calib_core.preprocess.motion import motion_check
from calib_core.simulate.noise import NoiseSpec, simulate_static
from calib_core.solvers.static_bias import solve_static_bias, solve_static_bias_stream
from calib_core.streamed import (
    Execution,
    MedianStep,
    Moments,
    SigmaClipFill,
    StreamedAllan,
    allan_deviation,
    joined_allan,
)

RATE = 100.0
# Different chunkings add the same numbers in a different order: a few ulp per sum,
# amplified by the cancellation of the second differences (|theta| / |d| ~ sqrt(N / m)).
REL = 1e-9


def _record(n: int = 40_003, seed: int = 1) -> np.ndarray:
    """White + random-walk noise on large offsets (an accelerometer's 9.8 m/s^2)."""
    rng = np.random.default_rng(seed)
    walk = np.cumsum(rng.normal(size=(n, 3)) * 1e-5, axis=0)
    return rng.normal(size=(n, 3)) * 0.01 + walk + [9.8, 0.0, 0.1]


def sigma_clip(x: np.ndarray, n_sigma: float = 3.0) -> np.ndarray:
    """The oracle of the n-sigma rule: its keep-mask of (N, C) samples on the whole array
    (one pass, NumPy's mean and std)."""
    mean, std = x.mean(axis=0), x.std(axis=0)
    return np.abs(x - mean) <= n_sigma * std


def _fill(x: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The oracle of its fill: rejected samples by linear interpolation (in sample index)
    of their kept neighbours, channel by channel (`np.interp`: the edge values beyond)."""
    out = x.copy()
    idx = np.arange(x.shape[0])
    for c in range(x.shape[1]):
        bad = ~keep[:, c]
        if bad.any():
            out[bad, c] = np.interp(idx[bad], idx[~bad], x[~bad, c])
    return out


def _chunks(x: np.ndarray, size: int):
    return [x[i : i + size] for i in range(0, x.shape[0], size)]


@pytest.mark.parametrize("size", [7, 1000, 30_000, 40_003])
@pytest.mark.parametrize("memory_rows", [100, 1 << 20, 40_004])
def test_streamed_allan_equals_in_memory_and_allantools(size, memory_rows):
    """Chunks smaller than the largest cluster (m = 2^14 here), a phase memory smaller
    than it (the longer lags then come from the history), and one that holds the whole
    phase (N + 1 rows: one buffer)."""
    x = _record()
    s = StreamedAllan(RATE, x.shape[0], 3, execution=Execution(memory_rows=memory_rows))
    for c in _chunks(x, size):
        s.push(c)
    got = s.result()
    ref = allan_deviation(x, RATE)
    assert np.array_equal(got.taus, ref.taus)
    assert np.allclose(got.adev, ref.adev, rtol=REL, atol=0)
    assert np.allclose(got.ci_high, ref.ci_high, rtol=REL, atol=0)
    for c in range(3):
        taus, adev, _, _ = allantools.oadev(x[:, c], rate=RATE, data_type="freq", taus="octave")
        k = min(taus.size, got.taus.size)
        assert np.allclose(taus[:k], got.taus[:k], rtol=1e-15)
        assert np.max(np.abs(got.adev[:k, c] / adev[:k] - 1)) <= REL


def test_streamed_allan_by_channel_with_helper_and_workspace_same_sums():
    """Each channel alone, half its sums on a helper thread, its whole phase in a shared
    workspace: the same sums, bit for bit, as the three channels in one StreamedAllan
    (each size's sum is added in the same order whichever thread sums it); the
    workspace is used and let go after each channel."""
    x = _record()
    n = x.shape[0]
    offset = x.mean(axis=0)
    together = StreamedAllan(RATE, n, 3, offset=offset, execution=Execution(memory_rows=n + 1))
    for chunk in _chunks(x, 1000):
        together.push(chunk)
    space = np.full(n + 1, np.nan)
    parts = []
    with ThreadPoolExecutor(1) as pool:
        on = Execution(submit=pool.submit, memory_rows=n + 1, workspace=space)
        for c in range(3):
            s = StreamedAllan(RATE, n, 1, offset=offset[c : c + 1], execution=on)
            for chunk in _chunks(x[:, c : c + 1], 1000):
                s.push(chunk)
            assert np.shares_memory(s._buf, space)
            s.release()  # the helper's last sums added
            assert np.array_equal(s.sums[:, 0], together.sums[:, c]), c
            parts.append(s)
    got, ref = joined_allan(parts), together.result()
    assert np.array_equal(got.adev, ref.adev) and np.array_equal(got.ci_low, ref.ci_low)
    with pytest.raises(ValueError, match="after release"):
        parts[0].push(x[:1, :1])


def test_sigma_rule_scan_equals_numpy():
    from calib_core.sigma_rule import outside

    rng = np.random.default_rng(3)
    x = rng.normal(2.0, 1.0, 10_000)
    x[[5, 77, 9000]] = [np.nan, np.inf, -np.inf]
    x[100] = 2.0 + 3.0  # at the limit: kept (|x - mean| <= limit)
    want = np.flatnonzero(~(np.abs(x - 2.0) <= 3.0))
    assert np.array_equal(outside(x, 2.0, 3.0), want)
    assert 100 not in want and {5, 77, 9000} <= set(want.tolist())
    assert outside(x[:0], 2.0, 3.0).size == 0


def test_streamed_allan_refuses_a_wrong_length():
    s = StreamedAllan(RATE, 100, 1)
    s.push(np.zeros((99, 1)))
    with pytest.raises(ValueError, match="99 samples pushed, 100 announced"):
        s.result()


def test_moments_merge_equals_numpy():
    x = _record(5001)
    m = Moments(3)
    for c in _chunks(x, 333):
        m.push(c)
    assert np.allclose(m.mean, x.mean(axis=0), rtol=1e-14, atol=0)
    assert np.allclose(m.std(ddof=1), x.std(axis=0, ddof=1), rtol=1e-12, atol=0)
    other = Moments(3)
    other.push(x[:10])
    other.merge(Moments(3))  # an empty stream changes nothing
    assert np.allclose(other.mean, x[:10].mean(axis=0), rtol=1e-15)


def test_sigma_clip_fill_in_chunks_equals_one_array():
    """Rejected runs at the start, across chunk edges and at the end are filled exactly
    as `_fill` does on the whole array."""
    x = _record(20_000)
    x[:3, 0] += 5.0
    x[995:1010, 1] += 1.0  # across the edge of the first 1000-row chunk
    x[-4:, 2] += 1.0
    keep = sigma_clip(x)
    first = Moments(3)
    first.push(x)
    clip = SigmaClipFill(first.mean, first.std(), 3.0)
    out = np.concatenate([clip.push(c) for c in _chunks(x, 1000)] + [clip.flush()])
    assert np.array_equal(out, _fill(x, keep))
    assert np.array_equal(clip.rejected, (~keep).sum(axis=0))
    kept_mean = [x[keep[:, c], c].mean() for c in range(3)]
    assert np.allclose(clip.kept.mean, kept_mean, rtol=1e-14, atol=0)


def test_median_step_equals_numpy():
    t = np.round(np.cumsum(np.random.default_rng(3).uniform(0.009, 0.011, 10_001)), 3)
    ms = MedianStep()
    for c in _chunks(t, 77):
        ms.push(c)
    assert ms.median() == np.median(np.diff(t))
    assert MedianStep(max_distinct=2) is not None
    many = MedianStep(max_distinct=2)
    with pytest.raises(ValueError, match="distinct time steps"):
        many.push(np.array([0.0, 1.0, 3.0, 6.0]))


@pytest.mark.parametrize("by_channel, memory_rows", [(False, 5000), (True, 5000), (True, 60_001)])
def test_streamed_static_bias_same_parameters_as_in_memory(by_channel, memory_rows):
    """One record through both paths: every parameter, its uncertainty and the noise
    terms the same to rounding (outliers included, so the clip and fill are exercised);
    streamed in one pass, or channel by channel with the longer lags from the history or
    the whole phase in a workspace, half the sums on a helper thread."""
    spec = NoiseSpec(arw=2e-3, bias_instability=2e-4, rrw=1e-4)
    rec = simulate_static(
        600.0,
        RATE,
        gyro_bias=np.array([0.02, -0.01, 0.005]),
        gyro_noise=spec,
        rng=np.random.default_rng(5),
    )
    rec.gyr[1000:1003, 0] += 1.0
    settings = {"up_axis": "+z", "n_sigma": 3.0}
    ref = solve_static_bias(rec, **settings)

    def chunks():
        for i in range(0, len(rec), 4096):
            yield rec.t[i : i + 4096], rec.gyr[i : i + 4096], rec.acc[i : i + 4096]

    both = np.hstack([rec.gyr, rec.acc])

    def channel(c):
        return (both[i : i + 4096, c : c + 1] for i in range(0, len(rec), 4096))

    with ThreadPoolExecutor(2) as pool:
        execution = Execution(
            submit=pool.submit,
            memory_rows=memory_rows,
            workspace=np.empty(len(rec) + 1) if memory_rows > len(rec) else None,
        )
        got = solve_static_bias_stream(
            chunks,
            label=rec.label or "record",
            channel_chunks=channel if by_channel else None,
            motion_label="record",
            execution=execution,
            **settings,
        )
    assert set(got.parameters) == set(ref.parameters)
    for name, p in ref.parameters.items():
        q = got.parameters[name]
        assert math.isclose(q.value, p.value, rel_tol=REL, abs_tol=1e-15), name
        assert math.isclose(q.std or 0.0, p.std or 0.0, rel_tol=1e-6, abs_tol=1e-15), name
    for sensor in ("gyr", "acc"):
        for a, b in zip(
            got.info["noise_parameters"][sensor], ref.info["noise_parameters"][sensor], strict=True
        ):
            for term in ("arw", "bias_instability", "rrw"):
                assert (a[term] is None) == (b[term] is None)
                if b[term] is not None:
                    assert math.isclose(a[term], b[term], rel_tol=1e-6), (sensor, term)
    assert got.info["outliers"] == ref.info["outliers"]
    assert got.warnings == ref.warnings
    # no first pass given: the solve computes the motion windows, in its one pass or in a
    # pass of their own before the channels'; the verdict and figures of the in-memory check
    (motion,) = [c for c in got.info["solver_checks"] if c["name"] == "motion:record"]
    want = motion_check("record", rec)
    assert motion["passed"] is want["passed"] and motion["detail"] == want["detail"]
    assert math.isclose(motion["value"], want["value"], rel_tol=1e-12)


@pytest.mark.parametrize("chunk", [1, 7, 64, 4096])
def test_sigma_clip_fill_runs_across_chunks_and_the_record_ends(chunk):
    """Rejected runs at the record's start and end, and across chunk boundaries: the same
    filled samples as the in-memory rule (bit for bit: the same bracketing points), and
    the kept moments from the whole record's less the rejected ones'."""
    rng = np.random.default_rng(11)
    x = rng.normal(0.0, 1.0, (3000, 3))
    x[:3, 0] += 40.0  # leading run
    x[-4:, 1] -= 40.0  # trailing run
    x[60:75, 2] += 40.0  # a run across chunks of 7 and 64
    total = Moments(3)
    total.push(x)
    keep = sigma_clip(x, 3.0)
    for given in (None, total):
        clip = SigmaClipFill(total.mean, total.std(), 3.0, total=given)
        y = np.concatenate([*(clip.push(c) for c in _chunks(x, chunk)), clip.flush()])
        assert np.array_equal(y, _fill(x, keep))
        assert np.array_equal(clip.rejected, (~keep).sum(axis=0))
        # sums of N values in another order: within N eps max|x| (Higham 4.2)
        bound = x.shape[0] * np.finfo(float).eps * np.abs(x).max()
        for c in range(3):
            kept = x[keep[:, c], c]
            assert abs(clip.kept.mean[c] - kept.mean()) <= bound
            assert abs(clip.kept.std(ddof=1)[c] - kept.std(ddof=1)) <= bound


def test_second_difference_sums_equal_numpy():
    """The compiled sums against NumPy's, for cluster sizes below, at and above a block,
    from several first terms (an empty range adds nothing)."""
    from calib_core.second_differences import BLOCK, runs_sum, span_sums

    theta = np.cumsum(_record(3 * BLOCK + 17)[:, 0] - 9.8)
    m = np.array([1, 3, BLOCK // 2, BLOCK, BLOCK + 5])
    first = np.array([0, 11, 5, BLOCK, theta.size])
    got = np.zeros(m.size)
    span_sums(theta, m, first, got, 0)
    for i in range(m.size):
        k = np.arange(first[i], theta.size - 2 * m[i])
        d = (theta[k + 2 * m[i]] - theta[k + m[i]]) - (theta[k + m[i]] - theta[k])
        # N terms summed in another order: within N eps of the sum (Higham 4.2)
        assert abs(got[i] - d @ d) <= max(k.size, 1) * np.finfo(float).eps * (d @ d)
    a, b, c = theta[10:], theta[5:-5], theta[:-10]
    d = (a - b) - (b - c)
    assert math.isclose(runs_sum(a, b, c), d @ d, rel_tol=a.size * np.finfo(float).eps)


def test_phase_equals_numpy_cumsum():
    """The compiled phase against NumPy's cumulative sum, continued from a start value:
    the same sequential sum (an offset subtracted first), so within N eps of max |phase|."""
    from calib_core.second_differences import phase

    x = _record(5000)[:, 0]
    out = np.empty_like(x)
    phase(x, 9.8, 1.5, out)
    ref = 1.5 + np.cumsum(x - 9.8)
    assert np.max(np.abs(out - ref)) <= x.size * np.finfo(float).eps * np.abs(ref).max()
