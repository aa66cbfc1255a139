"""Statistics of a record that arrives in chunks: nothing holds the whole record.

`Moments`: count, mean and variance per channel (Welford / Chan et al. merge of chunk
moments). `SigmaClipFill`: the static-bias outlier rule (n-sigma about the record's mean
and std) applied chunk by chunk, rejected samples filled by linear interpolation of their
kept neighbours exactly as `calib_core.solvers.static_bias` does on one array.
`StreamedAllan`: the overlapping Allan deviation (`calib_core.noise.allan_deviation`) from
a running cumulative sum: each chunk's second differences need the cumulative sum 2 m
samples back, so the last rows of the phase are kept (up to `memory_rows`); lags past
that are read from a `History` the caller supplies (a file in the pipelines, a list of
arrays by default). `MedianStep`: the median sample period (`Recording.sample_rate`)
from counts of the distinct time steps. `TemperatureTrend` and `RecordSummary`: what
the lab conditions take of a record.

Same numbers as the in-memory path to rounding (tests/test_streamed.py).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from calib_core.noise import AllanResult, allan_result, cluster_sizes


class Moments:
    """Count, mean and sum of squared deviations per channel, merged chunk by chunk.

    Each chunk's moments are computed with NumPy (pairwise sums) about the first row
    seen (so a constant channel has a variance of exactly 0, as in one pass) and merged
    by Chan, Golub & LeVeque's update, so the result matches one pass over the whole
    array to rounding whatever the chunking.
    """

    def __init__(self, channels: int):
        self.n = np.zeros(channels, dtype=np.int64)
        self._mean = np.zeros(channels)  # about `shift`
        self.m2 = np.zeros(channels)
        self.shift: np.ndarray | None = None

    @property
    def mean(self) -> np.ndarray:
        """Mean per channel."""
        return self._mean if self.shift is None else self.shift + self._mean

    def push(self, x: np.ndarray, keep: np.ndarray | None = None) -> None:
        """Add the rows of `x` (n, C); `keep` (n, C) bool: only the True samples count."""
        x = np.asarray(x, dtype=float)
        if x.shape[0] == 0:
            return
        if self.shift is None:
            self.shift = x[0].copy()
        x = x - self.shift
        if keep is None:
            nb = np.full(x.shape[1], x.shape[0], dtype=np.int64)
            mb = x.mean(axis=0)
            x -= mb  # x is this method's own shifted copy
            m2b = np.einsum("ij,ij->j", x, x)
        else:
            nb = keep.sum(axis=0)
            y = np.where(keep, x, 0.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                mb = np.where(nb > 0, y.sum(axis=0) / nb, 0.0)
            y -= mb
            y *= keep  # rejected samples: 0 about the mean as well
            m2b = np.einsum("ij,ij->j", y, y)
        self._merge(nb, mb, m2b)

    def _merge(self, nb: np.ndarray, mb: np.ndarray, m2b: np.ndarray) -> None:
        n = self.n + nb
        safe = np.maximum(n, 1)
        delta = mb - self._mean
        self._mean = np.where(n > 0, self._mean + delta * nb / safe, 0.0)
        self.m2 = self.m2 + m2b + delta**2 * self.n * nb / safe
        self.n = n

    def merge(self, other: Moments) -> None:
        """Add another stream's moments (Chan et al.)."""
        if other.shift is None:
            return
        if self.shift is None:
            self.shift = other.shift.copy()
        self._merge(other.n, other.mean - self.shift, other.m2)

    def std(self, ddof: int = 0) -> np.ndarray:
        """Standard deviation per channel (ddof as NumPy's)."""
        return np.sqrt(self.m2 / (self.n - ddof))


class MedianStep:
    """Median of the differences of a time column, from counts of its distinct steps.

    Exact (the same value as ``np.median(np.diff(t))``) while the record has at most
    `max_distinct` distinct steps (timestamps on a clock tick or printed with a fixed
    number of decimals have few); more raises, rather than return an approximate rate.
    """

    def __init__(self, max_distinct: int = 1_000_000):
        self.counts: Counter[float] = Counter()
        self.last: float | None = None
        self.max_distinct = max_distinct

    def push(self, t: np.ndarray) -> None:
        """Add the next timestamps (s)."""
        t = np.asarray(t, dtype=float)
        if t.size == 0:
            return
        steps = np.diff(t) if self.last is None else np.diff(t, prepend=self.last)
        self.last = float(t[-1])
        values, counts = np.unique(steps, return_counts=True)
        self.counts.update(dict(zip(values.tolist(), counts.tolist(), strict=True)))
        if len(self.counts) > self.max_distinct:
            raise ValueError(
                f"streamed sample rate: more than {self.max_distinct} distinct time steps; "
                "the median step is only kept exactly for fewer (read the record in memory)"
            )

    def median(self) -> float:
        """The median step, s (NumPy's: the mean of the two middle values for an even count)."""
        values = sorted(self.counts)
        cum = np.cumsum([self.counts[v] for v in values])
        total = int(cum[-1]) if len(cum) else 0
        if total == 0:
            raise ValueError("streamed sample rate: need >= 2 samples")
        lo = values[int(np.searchsorted(cum, (total - 1) // 2, side="right"))]
        hi = values[int(np.searchsorted(cum, total // 2, side="right"))]
        return float(np.mean([lo, hi]))


class SigmaClipFill:
    """The n-sigma rule of `calib_core.solvers.static_bias.sigma_clip` and its fill, in chunks.

    Parameters
    ----------
    mean, std : (C,) the whole record's mean and std (ddof 0), from a first pass.
    n_sigma : samples further than n_sigma * std from the mean are rejected.

    `push` returns the rows whose rejected samples can be filled already (each
    rejected run needs its next kept sample); `flush` returns the rest. Kept samples
    feed `kept` (`Moments`); `rejected` counts the others per channel.
    """

    def __init__(
        self, mean: np.ndarray, std: np.ndarray, n_sigma: float, total: Moments | None = None
    ):
        self.mean, self.limit = np.asarray(mean, float), n_sigma * np.asarray(std, float)
        channels = self.mean.size
        # With the whole record's moments (`total`), the kept samples' are those less the
        # rejected ones' (few): no pass over every sample for them.
        self.total = total
        self._kept = Moments(channels)
        self._rej_sum = np.zeros(channels)  # of (x - mean) over the rejected samples
        self._rej_sq = np.zeros(channels)  # of (x - mean)^2
        self.rejected = np.zeros(channels, dtype=np.int64)
        self._pending = np.empty((0, channels))
        self._pending_keep = np.empty((0, channels), dtype=bool)
        self._start = 0  # global index of the first pending row
        self._prev: list[tuple[int, float] | None] = [None] * channels

    def push(self, x: np.ndarray) -> np.ndarray:
        """Take the next rows (n, C); return the rows ready, rejected samples filled."""
        x = np.asarray(x, dtype=float)
        dev = np.subtract(x, self.mean)
        keep = np.abs(dev, out=np.empty_like(dev)) <= self.limit
        if self.total is None:
            self._kept.push(x, keep)
            self.rejected += x.shape[0] - keep.sum(axis=0)
        else:
            rows, cols = np.nonzero(~keep)
            self.rejected += np.bincount(cols, minlength=x.shape[1])
            out = dev[rows, cols]
            self._rej_sum += np.bincount(cols, weights=out, minlength=x.shape[1])
            self._rej_sq += np.bincount(cols, weights=out * out, minlength=x.shape[1])
        if len(self._pending):
            x = np.concatenate([self._pending, x])
            keep = np.concatenate([self._pending_keep, keep])
        ready = int(_last_true(keep).min()) + 1  # each channel kept at or after each row
        return self._emit(x, keep, ready)

    @property
    def kept(self) -> Moments:
        """Moments of the kept samples of each channel."""
        if self.total is None:
            return self._kept
        t = self.total
        out = Moments(self.mean.size)
        out.n = t.n - self.rejected
        # About the record's mean: sum (x - mean) over all is 0, sum of squares its m2
        # (plus n (mean_t - mean)^2, 0 when `mean` is the total's, as from a first pass).
        shift = t.mean - self.mean
        s1 = t.n * shift - self._rej_sum
        s2 = t.m2 + t.n * shift**2 - self._rej_sq
        mean_dev = s1 / np.maximum(out.n, 1)
        out.shift = self.mean.copy()
        out._mean = mean_dev
        out.m2 = np.maximum(s2 - s1 * mean_dev, 0.0)
        return out

    def flush(self) -> np.ndarray:
        """The rows held back; trailing rejected samples take the last kept value."""
        return self._emit(self._pending, self._pending_keep, self._pending.shape[0])

    def _emit(self, buf: np.ndarray, keep: np.ndarray, ready: int) -> np.ndarray:
        out, k = buf[:ready], keep[:ready]
        last = _last_true(k)
        filled = False
        cols, rows = np.nonzero(~k.T)  # channel by channel, rows ascending
        ends = np.searchsorted(cols, np.arange(k.shape[1] + 1))
        for c in np.flatnonzero(ends[1:] > ends[:-1]):
            if not filled:
                out, filled = out.copy(), True
            bad = rows[ends[c] : ends[c + 1]]
            xp, fp = self._neighbours(buf, keep, bad, c)
            out[bad, c] = np.interp(self._start + bad, xp, fp)
        for c in np.flatnonzero(last >= 0):
            self._prev[c] = (self._start + int(last[c]), float(buf[last[c], c]))
        self._pending, self._pending_keep = buf[ready:].copy(), keep[ready:].copy()
        self._start += ready
        return out

    def _neighbours(
        self, buf: np.ndarray, keep: np.ndarray, bad: np.ndarray, c: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Global indices and values of the kept samples either side of each run of
        rejected rows `bad` (ascending) of channel `c`: the only points `np.interp` of
        all kept samples uses, so its values are the same."""
        brk = np.flatnonzero(np.diff(bad) > 1)
        left = np.concatenate([bad[:1], bad[brk + 1]]) - 1
        right = np.concatenate([bad[brk], bad[-1:]]) + 1
        after = np.flatnonzero(keep[right[-1] :, c])  # the last run's: beyond `ready`
        if after.size:
            right[-1] += after[0]
        else:  # none (the record's end): np.interp keeps the last kept value
            right = right[:-1]
        xp = np.unique(np.concatenate([left[left >= 0], right]))
        fp = buf[xp, c]
        xp = xp + self._start
        if left[0] < 0:
            if self._prev[c] is None:
                # leading rejected samples take the first kept value (np.interp's rule)
                if xp.size == 0:
                    raise ValueError(f"sigma clip: channel {c} has no kept sample")
                return xp, fp
            xp = np.concatenate([[self._prev[c][0]], xp])
            fp = np.concatenate([[self._prev[c][1]], fp])
        if xp.size == 0:
            raise ValueError(f"sigma clip: channel {c} has no kept sample")
        return xp, fp


def _last_true(mask: np.ndarray) -> np.ndarray:
    """(C,) index of the last True row of each column of `mask` (n, C), -1 where none."""
    if mask.shape[0] == 0:
        return np.full(mask.shape[1], -1)
    last = mask.shape[0] - 1 - np.argmax(mask[::-1], axis=0)
    return np.where(mask.any(axis=0), last, -1)


class History(Protocol):
    """Where `StreamedAllan` keeps the phase rows it needs beyond its memory."""

    def append(self, rows: np.ndarray) -> None:
        """Add rows at the end."""

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows start..stop-1 (global row indices, 0 = the phase's first value)."""


class ListHistory:
    """A History in memory (for records that fit; the pipelines give a file)."""

    def __init__(self) -> None:
        self._rows = np.empty((0, 0))
        self._n = 0

    def append(self, rows: np.ndarray) -> None:
        if self._n + rows.shape[0] > self._rows.shape[0]:  # grow by doubling
            grown = np.empty((2 * (self._n + rows.shape[0]), rows.shape[1]))
            if self._n:
                grown[: self._n] = self._rows[: self._n]
            self._rows = grown
        self._rows[self._n : self._n + rows.shape[0]] = rows
        self._n += rows.shape[0]

    def read(self, start: int, stop: int) -> np.ndarray:
        return self._rows[start:stop]


BLOCK_ROWS = 8192  # rows of the Allan sums' blocks: two (rows, 6) temporaries in cache
_ONES = np.ones(BLOCK_ROWS)


class StreamedAllan:
    """Overlapping Allan deviation of a record pushed in chunks (`allan_deviation`'s numbers).

    Parameters
    ----------
    rate_hz : sample rate, Hz.
    n_samples : the record's length N (from a first pass): it sets the cluster sizes.
    channels : C.
    taus : as `calib_core.noise.cluster_sizes`.
    offset : (C,) subtracted before the cumulative sum (the Allan variance does not
        depend on it; the record's mean keeps the sum small, as in memory). None: the
        first chunk's mean.
    memory_rows : phase rows kept in memory; cluster sizes with 2 m beyond it read their
        lagged rows from `history`.
    history : `History` of every phase row, needed only when 2 m > memory_rows for
        some m; default `ListHistory` (in memory).
    map_ : how the cluster sizes of a chunk are run: the builtin `map` (one after the
        other) or a thread pool's `map` (NumPy releases the GIL on whole-array work, so
        they share the cores); the sums do not depend on it.
    """

    def __init__(
        self,
        rate_hz: float,
        n_samples: int,
        channels: int,
        *,
        taus: str | np.ndarray = "octave",
        offset: np.ndarray | None = None,
        memory_rows: int = 1 << 20,
        history: History | None = None,
        map_: Callable[[Callable, Iterable], Iterable] = map,
    ):
        if not rate_hz > 0:
            raise ValueError(f"streamed Allan deviation: rate_hz must be > 0, got {rate_hz}")
        self.rate_hz, self.n_samples = float(rate_hz), int(n_samples)
        self.m = cluster_sizes(n_samples, rate_hz, taus)
        self.keep_rows = int(min(2 * self.m.max(), max(memory_rows, 1)))
        self.spills = bool((2 * self.m > self.keep_rows).any())
        self.history = history if history is not None or not self.spills else ListHistory()
        self.offset = None if offset is None else np.asarray(offset, float)
        self.sums = np.zeros((self.m.size, channels))
        self._tail = np.zeros((1, channels))  # theta_0 = 0
        self._j = 1  # phase rows seen (theta has N + 1)
        self.map = map_
        if self.spills:
            self.history.append(self._tail)

    def push(self, x: np.ndarray) -> None:
        """Add the next samples (n, C), unit of the rate."""
        x = np.asarray(x, dtype=float)
        if x.shape[0] == 0:
            return
        if not np.isfinite(x).all():
            raise ValueError("streamed Allan deviation: samples contain NaN or infinite values")
        if self.offset is None:
            self.offset = x.mean(axis=0)
        theta = np.cumsum(x - self.offset, axis=0)
        theta += self._tail[-1]
        j0, j1 = self._j, self._j + x.shape[0]
        if self.spills:
            self.history.append(theta)
        window = np.concatenate([self._tail, theta])
        g0 = j0 - self._tail.shape[0]  # global index of window[0]
        todo = [(k, int(m)) for k, m in enumerate(self.m) if max(j0, 2 * m) < j1]
        for _ in self.map(lambda km: self._add(km[0], km[1], window, g0, j0, j1), todo):
            pass
        self._tail = window[-self.keep_rows :]  # a view: the window lives until the next push
        self._j = j1

    def _add(self, k: int, m: int, window: np.ndarray, g0: int, j0: int, j1: int) -> None:
        """Add the squared second differences ending in rows j0..j1-1 for cluster size m."""
        lo = max(j0, 2 * m)
        if lo - 2 * m >= g0:
            # (theta_{k+2m} - theta_{k+m}) - (theta_{k+m} - theta_k), in blocks whose
            # temporaries stay in the processor's cache.
            span = window[lo - 2 * m - g0 : j1 - g0]
            n, total = j1 - lo, np.zeros(span.shape[1])
            tmp = np.empty((2, min(n, BLOCK_ROWS), span.shape[1]))
            for s in range(0, n, BLOCK_ROWS):
                e = min(s + BLOCK_ROWS, n)
                mid = span[s + m : e + m]
                a = np.subtract(span[s + 2 * m : e + 2 * m], mid, out=tmp[0, : e - s])
                b = np.subtract(mid, span[s:e], out=tmp[1, : e - s])
                a -= b
                # column sums of squares as a product with ones (BLAS): faster than einsum
                total += _ONES[: e - s] @ np.multiply(a, a, out=b)
            self.sums[k] += total
            return
        else:
            one = self.history.read(lo - m, j1 - m)
            d = np.subtract(window[lo - g0 : j1 - g0], one)
            d -= one
            d += self.history.read(lo - 2 * m, j1 - 2 * m)
        self.sums[k] += np.einsum("ij,ij->j", d, d)

    def result(self) -> AllanResult:
        """The Allan deviation (K, C), once all N samples are in."""
        n = self._j - 1
        if n != self.n_samples:
            raise ValueError(
                f"streamed Allan deviation: {n} samples pushed, {self.n_samples} announced"
            )
        denom = (2.0 * (n + 1 - 2 * self.m))[:, None] * self.rate_hz**2
        return allan_result(self.m, self.sums / denom, n, self.rate_hz)


def columns(result: AllanResult, cols: slice) -> AllanResult:
    """The channels `cols` of a multi-channel result (e.g. the gyro's of a (K, 6) one)."""
    return AllanResult(
        result.taus,
        result.adev[:, cols],
        result.n_clusters,
        result.ci_low[:, cols],
        result.ci_high[:, cols],
        result.edf,
        result.rate_hz,
        result.n_samples,
    )


class TemperatureTrend:
    """The sensor temperature of a record pushed in chunks, as `calib_core.conditions`
    judges it: the means of the pieces `np.array_split` cuts its finite values into
    (`temperature_spread`'s 1-s means) and the slope of its straight-line fit against
    time (`temperature_drift`'s, when every value is finite).

    Parameters
    ----------
    n_finite : the record's count of finite temperatures (from the first pass).
    block : samples per mean (the rounded sample rate, Hz, as `temperature_spread`).
    """

    def __init__(self, n_finite: int, block: int):
        self.k = max(1, n_finite // max(1, block))
        q, r = divmod(n_finite, self.k)
        pieces = np.arange(self.k)
        self.starts = pieces * q + np.minimum(pieces, r)  # array_split's piece starts
        self.sizes = np.diff(np.append(self.starts, n_finite))
        self.sums = np.zeros(self.k)
        self.seen = 0
        self.all_finite = True
        self.fit = Moments(2)  # (t, temp): means and squared deviations
        self.cross = 0.0  # co-moment of t and temp about their means
        self.n_finite = n_finite

    def push(self, t: np.ndarray, temp: np.ndarray) -> None:
        """Add the next samples' times (s) and temperatures (deg C, NaN where none)."""
        finite = np.isfinite(temp)
        v = temp if finite.all() else temp[finite]
        self.all_finite &= bool(v.size == temp.size)
        if v.size == 0:
            return
        piece = np.searchsorted(self.starts, self.seen + np.arange(v.size), side="right") - 1
        lo = int(piece[0])
        self.sums[lo : int(piece[-1]) + 1] += np.bincount(piece - lo, weights=v)
        self.seen += v.size
        if self.all_finite:
            self._push_fit(np.asarray(t, float), v)

    def _push_fit(self, t: np.ndarray, v: np.ndarray) -> None:
        """Chan et al.'s merge of the co-moment, beside the two channels' moments."""
        n_a, mean_a = int(self.fit.n[0]), self.fit.mean
        x = np.column_stack([t, v])
        mean_b = x.mean(axis=0)
        d = x - mean_b
        cross_b = float(d[:, 0] @ d[:, 1])
        if n_a:
            delta = mean_b - mean_a
            cross_b += float(delta[0] * delta[1]) * n_a * len(v) / (n_a + len(v))
        self.cross += cross_b
        self.fit.push(x)

    def means(self) -> np.ndarray | None:
        """The pieces' means (deg C); None when no temperature was finite."""
        if self.n_finite == 0:
            return None
        if self.seen != self.n_finite:
            raise ValueError(
                f"temperature: {self.seen} finite values pushed, {self.n_finite} announced"
            )
        return self.sums / self.sizes

    def slope(self) -> float | None:
        """The straight-line fit's slope, deg C/s; None unless every value was finite."""
        if not self.all_finite or self.fit.n[0] < 2 or self.fit.m2[0] == 0:
            return None
        return self.cross / float(self.fit.m2[0])


@dataclass
class RecordSummary:
    """What the lab conditions (`calib_core.conditions`) take of one record that was
    streamed in chunks, in place of its `Recording`: length, time span, the sensor
    temperature's 1-s means and trend. No reference channels."""

    label: str
    n: int
    t_first: float
    t_last: float
    temp_means: np.ndarray | None  # deg C, `TemperatureTrend.means`
    temp_slope: float | None  # deg C/s, `TemperatureTrend.slope`
    reference: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return self.n

    @property
    def duration(self) -> float:
        """Time span covered, s."""
        return self.t_last - self.t_first if self.n else 0.0
