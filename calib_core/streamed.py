"""Statistics of a record that arrives in chunks: nothing holds the whole record; a
record in memory is the one-chunk case (one implementation of each statistic).

`Moments`: count, mean and variance per channel (Welford / Chan et al. merge of chunk
moments). `SigmaClipFill`: the static-bias outlier rule (n-sigma about the record's mean
and std, one pass) applied chunk by chunk, rejected samples filled by linear
interpolation (in sample index) of their kept neighbours, as `np.interp` of all kept
samples would. `StreamedAllan`: the overlapping Allan deviation from a running
cumulative sum (`allan_deviation`, of a record in memory, is its one-chunk case): each
chunk's second differences need the cumulative sum 2 m samples back, so the last rows
of the phase are kept (up to `memory_rows`); lags past that are read from a `History`
the caller supplies (a file in the pipelines, a list of arrays by default).
`Execution`: what a caller gives the streamed computations to run on (a helper beside
the calling thread, phase memory, a history, a workspace); the numbers never depend on
it. `MedianStep`: the median sample period (`Recording.sample_rate`) from counts of the
distinct time steps. `TemperatureTrend` and `RecordSummary`: what the lab conditions
take of a record.

The chunking changes the numbers by rounding only (tests/test_streamed.py; allantools
is the Allan deviation's oracle).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

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

    def columns(self, cols: slice) -> Moments:
        """The moments of the channels `cols` (a copy)."""
        out = Moments(0)
        out.n, out._mean, out.m2 = self.n[cols].copy(), self._mean[cols].copy(), self.m2[cols]
        out.shift = None if self.shift is None else self.shift[cols].copy()
        return out

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
    """The static-bias solve's n-sigma rule (one pass) and its fill, in chunks.

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
        self._pending_bad: list[np.ndarray] = [np.empty(0, np.int64)] * channels
        self._start = 0  # global index of the first pending row
        self._prev: list[tuple[int, float] | None] = [None] * channels

    def push(self, x: np.ndarray) -> np.ndarray:
        """Take the next rows (n, C); return the rows ready, rejected samples filled."""
        x = np.asarray(x, dtype=float)
        bad = self._rejected(x)
        if len(self._pending):
            held = self._pending.shape[0]
            x = np.concatenate([self._pending, x])
            pairs = zip(self._pending_bad, bad, strict=True)
            bad = [np.concatenate([p, b + held]) for p, b in pairs]
        # each channel has a kept sample at or after every row before `ready`
        ready = min(_last_kept(b, x.shape[0]) for b in bad) + 1
        return self._emit(x, bad, ready)

    def _rejected(self, x: np.ndarray) -> list[np.ndarray]:
        """Row indices (ascending) of each channel's rejected samples of the new rows `x`;
        their count and sums (or the kept samples' moments) taken."""
        from calib_core.sigma_rule import outside  # Numba: when used

        bad = []
        for c in range(x.shape[1]):
            bad.append(outside(x[:, c], float(self.mean[c]), float(self.limit[c])))
            if self.total is not None:
                out = x[bad[-1], c] - self.mean[c]
                self._rej_sum[c] += out.sum()
                self._rej_sq[c] += out @ out
        counts = np.array([b.size for b in bad])
        if self.total is None:
            keep = np.ones(x.shape, dtype=bool)
            for c, b in enumerate(bad):
                keep[b, c] = False
            self._kept.push(x, keep)
        self.rejected += counts
        return bad

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
        return self._emit(self._pending, self._pending_bad, self._pending.shape[0])

    def _emit(self, buf: np.ndarray, bad: list[np.ndarray], ready: int) -> np.ndarray:
        out = buf[:ready]
        filled = False
        for c, rows in enumerate(bad):
            now = rows[: np.searchsorted(rows, ready)]
            if now.size:
                if not filled:
                    out, filled = out.copy(order="K"), True
                xp, fp = self._neighbours(buf, rows, now, c)
                out[now, c] = np.interp(self._start + now, xp, fp)
            last = _last_kept(now, ready)
            if last >= 0:
                self._prev[c] = (self._start + last, float(buf[last, c]))
        self._pending = buf[ready:].copy()
        self._pending_bad = [rows[np.searchsorted(rows, ready) :] - ready for rows in bad]
        self._start += ready
        return out

    def _neighbours(
        self, buf: np.ndarray, rows: np.ndarray, now: np.ndarray, c: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Global indices and values of the kept samples either side of each run of
        rejected rows `now` (ascending, the first of channel c's rejected `rows`) : the
        only points `np.interp` of all kept samples uses, so its values are the same."""
        brk = np.flatnonzero(np.diff(now) > 1)
        left = np.concatenate([now[:1], now[brk + 1]]) - 1
        right = np.concatenate([now[brk], now[-1:]]) + 1
        # the last run may go on past `ready`: its end is where the rejected rows stop
        run = rows[now.size :]
        gaps = np.flatnonzero(run - np.arange(right[-1], right[-1] + run.size) != 0)
        right[-1] += gaps[0] if gaps.size else run.size
        if right[-1] >= buf.shape[0]:  # none (the record's end): np.interp keeps the last
            right = right[:-1]  # kept value
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


def _last_kept(rejected: np.ndarray, n: int) -> int:
    """The last row of 0..n-1 not in `rejected` (ascending row indices), -1 if none."""
    k = rejected.size
    if k == 0 or rejected[-1] != n - 1:
        return n - 1
    # the trailing run of rejected rows n - r .. n - 1: where the indices stop being
    # consecutive from the end
    tail = rejected - np.arange(n - k, n)
    stop = np.flatnonzero(tail != 0)
    return int(rejected[stop[-1] + 1]) - 1 if stop.size else n - k - 1


class History(Protocol):
    """Where `StreamedAllan` keeps the phase rows it needs beyond its memory."""

    def append(self, rows: np.ndarray) -> None:
        """Add rows at the end: (C, n), channel by channel."""

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows start..stop-1 (global row indices, 0 = the phase's first value):
        (C, stop - start)."""


class ListHistory:
    """A History in memory (for records that fit; the pipelines give a file)."""

    def __init__(self) -> None:
        self._rows = np.empty((0, 0))
        self._n = 0

    def append(self, rows: np.ndarray) -> None:
        if self._n + rows.shape[1] > self._rows.shape[1]:  # grow by doubling
            grown = np.empty((rows.shape[0], 2 * (self._n + rows.shape[1])))
            if self._n:
                grown[:, : self._n] = self._rows[:, : self._n]
            self._rows = grown
        self._rows[:, self._n : self._n + rows.shape[1]] = rows
        self._n += rows.shape[1]

    def read(self, start: int, stop: int) -> np.ndarray:
        return self._rows[:, start:stop]


class Pending(Protocol):
    """A call in progress (a `concurrent.futures.Future`): `result` waits for it and
    raises its error."""

    def result(self) -> Any: ...


class Done:
    """fn(*args) called now; `result` its value (a `Pending` without a helper)."""

    def __init__(self, fn: Callable, *args: Any) -> None:
        self.value = fn(*args)

    def result(self) -> Any:
        return self.value


@dataclass(frozen=True)
class Execution:
    """What the streamed computations run on, given by their caller (the pipelines make
    it; the science starts no thread and opens no file). The numbers never depend on it.

    submit : submit(fn, *args) -> a `Pending` (an executor's ``submit``): a helper of at
        least two workers beside the calling thread, where work that releases the GIL
        (NumPy, the compiled sums) runs meanwhile; None: everything in line.
    memory_rows : phase rows each Allan deviation keeps in memory; the longer lags are read
        from `new_history()`.
    new_history : a new `History` for them (a file in the pipelines); None: in memory.
    workspace : float64 values holding a channel's whole phase when `memory_rows` holds
        it (see `StreamedAllan`); None: new buffers.
    """

    submit: Callable[..., Pending] | None = None
    memory_rows: int = 1 << 20
    new_history: Callable[[], History] | None = None
    workspace: np.ndarray | None = None

    def run(self, fn: Callable, *args: Any) -> Pending:
        """fn(*args) on the helper, or now without one."""
        return self.submit(fn, *args) if self.submit is not None else Done(fn, *args)


IN_LINE = Execution()


class StreamedAllan:
    """Overlapping Allan deviation of a record pushed in chunks.

    Parameters
    ----------
    rate_hz : sample rate, Hz.
    n_samples : the record's length N (from a first pass): it sets the cluster sizes.
    channels : C.
    taus : as `calib_core.noise.cluster_sizes`.
    offset : (C,) subtracted before the cumulative sum (the Allan variance does not
        depend on it; the record's mean keeps the sum small, as in memory). None: the
        first chunk's mean.
    execution : its ``memory_rows`` phase rows are kept in memory; cluster sizes with 2 m
        beyond them read their lagged rows from a history (``new_history()``, or in
        memory), every phase row kept there. At least N + 1: the whole phase, in one
        buffer (no history, no rows moved), of the ``workspace`` when it holds C (N + 1)
        values (a caller passes the same one to the channels it solves in turn, whose
        pages are then touched once). With ``submit``, half of the cluster sizes held in
        memory are summed on the helper (the compiled sums release the GIL).

    The phase is kept channel by channel (each channel's rows contiguous); the squared
    second differences are summed by the compiled loops of
    `calib_core.second_differences`.
    """

    def __init__(
        self,
        rate_hz: float,
        n_samples: int,
        channels: int,
        *,
        taus: str | np.ndarray = "octave",
        offset: np.ndarray | None = None,
        execution: Execution = IN_LINE,
    ):
        if not rate_hz > 0:
            raise ValueError(f"Allan deviation: rate_hz must be > 0, got {rate_hz}")
        self.rate_hz, self.n_samples = float(rate_hz), int(n_samples)
        self.m = cluster_sizes(n_samples, rate_hz, taus)
        self.keep_rows = int(min(2 * self.m.max(), max(execution.memory_rows, 1)))
        self.spills = bool((2 * self.m > self.keep_rows).any())
        self.history: History | None = None
        if self.spills:
            new = execution.new_history
            self.history = new() if new is not None else ListHistory()
        self.offset = None if offset is None else np.asarray(offset, float)
        self.helper, self.workspace = execution.submit, execution.workspace
        self._beside: tuple | None = None  # the helper's sums in progress (`_settle`)
        self.sums = np.zeros((self.m.size, channels))
        # The phase's last keep_rows rows and the newest chunk's: column i is phase row
        # self._g0 + i; theta_0 = 0 (allocated at the first push, `_room`).
        self._buf: np.ndarray | None = np.zeros((channels, 1))
        self._fill, self._g0 = 1, 0
        self._j = 1  # phase rows seen (theta has N + 1)
        if self.spills:
            self.history.append(self._buf[:, :1])

    def push(self, x: np.ndarray) -> None:
        """Add the next samples (n, C), unit of the rate."""
        x = np.asarray(x, dtype=float)
        n = x.shape[0]
        if n == 0:
            return
        if not np.isfinite(x).all():
            raise ValueError("Allan deviation: the samples contain NaN or infinite values")
        if self.offset is None:
            self.offset = x.mean(axis=0)
        from calib_core.second_differences import phase  # Numba: when used

        if self._buf is None:
            raise ValueError("Allan deviation: samples pushed after release()")
        self._room(n)
        theta = self._buf[:, self._fill : self._fill + n]
        for c in range(x.shape[1]):
            phase(x[:, c], float(self.offset[c]), float(self._buf[c, self._fill - 1]), theta[c])
        if self.spills:
            self.history.append(theta)
        self._fill += n
        j0, j1 = self._j, self._j + n
        lagged = self._lagged(j0, j1)
        for c in range(x.shape[1]):
            self._channel(c, j0, j1, lagged)
        self._j = j1

    def release(self) -> None:
        """Let the phase rows go once every sample is in (the sums are all `result`
        needs); a later push raises."""
        self._settle()
        self._buf = None

    def _settle(self) -> None:
        """Wait for the helper's sums of the last chunk and add them (its error raised)."""
        if self._beside is not None:
            job, c, rows, part = self._beside
            self._beside = None
            job.result()
            self.sums[rows, c] += part

    def _room(self, n: int) -> None:
        """Make room for n more rows, keeping the last keep_rows."""
        if self._fill + n <= self._buf.shape[1]:
            return
        self._settle()  # the helper reads the rows about to move
        keep = min(self.keep_rows, self._fill)
        # Room for keep_rows more rows beyond the kept ones: each row is moved about once;
        # never more than the rows still to come (the whole phase: one buffer).
        rest = self.n_samples + 1 - (self._g0 + self._fill - keep)
        size = max(min(2 * self.keep_rows + n, rest), keep + n)
        if size > self._buf.shape[1] or self._buf.shape[1] > 2 * size:
            grown = self._new_buffer(size, whole=size >= rest)
            grown[:, :keep] = self._buf[:, self._fill - keep : self._fill]
            self._buf = grown
        else:
            self._buf[:, :keep] = self._buf[:, self._fill - keep : self._fill].copy()
        self._g0 += self._fill - keep
        self._fill = keep

    def _new_buffer(self, size: int, whole: bool) -> np.ndarray:
        """A (C, size) buffer: of the workspace when it holds every row to come (`whole`:
        never moved again) and the workspace is large enough, else a new one."""
        channels, ws = self._buf.shape[0], self.workspace
        if whole and ws is not None and ws.size >= channels * size:
            return ws[: channels * size].reshape(channels, size)
        return np.empty((channels, size))

    def _lagged(self, j0: int, j1: int) -> dict[int, tuple[int, np.ndarray]]:
        """The history rows the cluster sizes beyond memory need for rows j0..j1-1: for each
        lag b (m and 2 m of each such m), (first row, (C, rows)) of rows max(j0, b) - b
        .. j1 - b - 1, read once for the two cluster sizes that use a lag."""
        out: dict[int, tuple[int, np.ndarray]] = {}
        for m in self.m[2 * self.m > self.keep_rows]:
            if max(j0, 2 * m) >= j1:
                continue
            for b in (int(m), int(2 * m)):
                if b not in out:
                    lo = max(j0, b) - b
                    out[b] = (lo, self.history.read(lo, j1 - b))
        return out

    def _channel(self, c: int, j0: int, j1: int, lagged: dict) -> None:
        """Add channel c's squared second differences ending in rows j0..j1-1, every m."""
        from calib_core.second_differences import runs_sum, span_sums  # Numba: when used

        col, g0 = self._buf[c], self._g0
        near = 2 * self.m <= self.keep_rows  # theta_{lo-2m} .. theta_{j1-1} are in memory
        lo = np.maximum(j0, 2 * self.m)
        sums = np.zeros(self.m.size)  # the near sizes first (m ascending)
        first, m_near = lo[near] - 2 * self.m[near], self.m[near]
        first -= g0
        span = col[: j1 - g0]
        # the larger sizes (their lagged rows from memory, the slower) beside, added when
        # done (`_settle`): meanwhile this thread goes on to the next chunk's phase
        half = _halves(m_near) if self.helper is not None else first.size
        if half < first.size:
            self._settle()  # one chunk's at a time: each size's sums added in order
            part = np.zeros(first.size - half)
            job = self.helper(span_sums, span, m_near[half:], first[half:], part, j0 - g0)
            self._beside = (job, c, slice(half, first.size), part)
        span_sums(span, m_near[:half], first[:half], sums[:half], j0 - g0)
        for k in np.flatnonzero(~near & (lo < j1)).tolist():
            m, start = int(self.m[k]), int(lo[k])
            (a, mid), (b, old) = lagged[m], lagged[2 * m]
            n = j1 - start
            sums[k] = runs_sum(
                col[start - g0 : j1 - g0],
                mid[c, start - m - a : start - m - a + n],
                old[c, start - 2 * m - b : start - 2 * m - b + n],
            )
        self.sums[:, c] += sums

    def result(self) -> AllanResult:
        """The Allan deviation (K, C), once all N samples are in."""
        return joined_allan([self])


def _halves(m: np.ndarray) -> int:
    """Where to cut the cluster sizes m (ascending) into two parts of about equal work: a
    size of a block or more reads its lagged runs from memory rather than the cache, and
    takes about three times as long (2.6 measured: 57 M samples, 12 sizes below a block
    0.13 s a channel, 13 above 0.38 s)."""
    from calib_core.second_differences import BLOCK

    work = np.where(m >= BLOCK, 3, 1).cumsum()
    return int(np.searchsorted(work, work[-1] / 2)) if m.size > 1 else m.size


def joined_allan(parts: list[StreamedAllan], one_channel: bool = False) -> AllanResult:
    """The Allan deviation (K, sum of C) of the channels of several `StreamedAllan` of one
    record (the same rate, length and cluster sizes), side by side in their order, once
    all N samples are in each; (K,) with `one_channel` (a record of one channel)."""
    one = parts[0]
    for part in parts:
        part._settle()
        n = part._j - 1
        if n != part.n_samples:
            raise ValueError(f"Allan deviation: {n} samples pushed, {part.n_samples} announced")
        if (part.n_samples, part.rate_hz) != (one.n_samples, one.rate_hz):
            raise ValueError("Allan deviation: the parts are of different records")
    n, rate = one.n_samples, one.rate_hz
    denom = (2.0 * (n + 1 - 2 * one.m))[:, None] * rate**2
    avar = np.hstack([part.sums for part in parts]) / denom
    return allan_result(one.m, avar[:, 0] if one_channel else avar, n, rate)


def allan_deviation(
    x: np.ndarray, rate_hz: float, taus: str | np.ndarray = "octave"
) -> AllanResult:
    """Overlapping Allan deviation of a rate signal in memory: `StreamedAllan`'s of one
    chunk, its whole phase in one buffer.

    Parameters
    ----------
    x : (N,) or (N, C) samples of a rate (rad/s, m/s^2, ...).
    rate_hz : sample rate, Hz.
    taus : "octave", "log" or an array of cluster times in s (see
        `calib_core.noise.cluster_sizes`).

    Returns
    -------
    AllanResult with adev of shape (K,) or (K, C) in the unit of `x`.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim not in (1, 2):
        raise ValueError(f"allan_deviation: x must be (N,) or (N, C), got shape {x.shape}")
    cols = x.reshape(x.shape[0], -1)
    n = cols.shape[0]
    allan = StreamedAllan(
        rate_hz, n, cols.shape[1], taus=taus, execution=Execution(memory_rows=n + 1)
    )
    allan.push(cols)
    return joined_allan([allan], one_channel=x.ndim == 1)


def load_compiled() -> None:
    """Load the compiled loops of the streamed statistics (Numba's cache; compiled the
    first time after installing) by one call each on a few samples, so that a solve
    starts at once."""
    clip = SigmaClipFill(np.zeros(1), np.ones(1), 3.0)
    warm = StreamedAllan(1.0, 5, 1)
    warm.push(clip.push(np.zeros((5, 1))))


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
