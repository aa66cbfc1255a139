"""The Recording: one stretch of IMU samples in SI units."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True, eq=False)
class Recording:
    """IMU samples of one file or one segment, in SI units.

    Attributes
    ----------
    t : (N,) float, s, strictly increasing.
    acc : (N, 3) float, specific force, m/s^2.
    gyr : (N, 3) float, angular rate, rad/s.
    temp : (N,) float, deg C, or None.
    reference : named reference channels on the same time base, e.g.
        ``"table_angle"`` (N,) rad, ``"table_rate"`` (N,) rad/s.
    label : segment label (``"x_up"``, ``"z_ccw"``, ...) or None.
    source : where the samples came from (file name, line range), for messages.
    devices : the firmware's ids of the sensors that made the samples, when the log records
        them: ``accel`` / ``gyro`` (a PX4 ULog's device_id), ``imu`` (an ArduPilot DataFlash
        log's 0-based IMU instance); what an autopilot file must name to take effect.
    findings : what its reader found about the record without refusing it (a log cut
        while written, read to its last whole record), each as CheckResult fields
        (``name`` "record:...", value, limit, passed, detail): a run's checks name them.
    """

    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    temp: np.ndarray | None = None
    reference: dict[str, np.ndarray] = field(default_factory=dict)
    label: str | None = None
    source: str | None = None
    devices: dict[str, int] = field(default_factory=dict)
    findings: tuple[dict, ...] = ()

    def __post_init__(self) -> None:
        where = f" ({self.source})" if self.source else ""
        n = np.shape(self.t)[0] if np.ndim(self.t) == 1 else -1
        if n < 0:
            raise ValueError(f"Recording{where}: t must be 1-D, got shape {np.shape(self.t)}")
        for name in ("acc", "gyr"):
            shape = np.shape(getattr(self, name))
            if shape != (n, 3):
                raise ValueError(f"Recording{where}: {name} must have shape ({n}, 3), got {shape}")
        if self.temp is not None and np.shape(self.temp) != (n,):
            raise ValueError(
                f"Recording{where}: temp must have shape ({n},), got {np.shape(self.temp)}"
            )
        for key, values in self.reference.items():
            if np.shape(values)[:1] != (n,):
                raise ValueError(
                    f"Recording{where}: reference channel {key!r} has {np.shape(values)[0]} "
                    f"samples, expected {n}"
                )

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        """Time span covered, s."""
        return float(self.t[-1] - self.t[0]) if len(self) else 0.0

    @property
    def sample_rate(self) -> float:
        """Median sample rate, Hz."""
        if len(self) < 2:
            raise ValueError(f"Recording ({self.source}): need >= 2 samples for a sample rate")
        return float(1.0 / np.median(np.diff(self.t)))

    def window(
        self, start: float, end: float, label: str | None = None, *, increasing: bool = False
    ) -> Recording:
        """Samples with start <= t < end (s), as a new Recording.

        Where those samples are one contiguous run (always, for increasing t),
        the new Recording's arrays are views of this one's (no copy, as
        `select` with a slice); otherwise copies. `increasing`: the caller knows
        t strictly increases (`strictly_increasing`), so the window is found by
        bisection instead of a pass over every sample (the same samples).
        """
        if increasing and not (np.isnan(start) or np.isnan(end)):
            lo, hi = (int(i) for i in np.searchsorted(self.t, [start, end], side="left"))
            return self.select(slice(lo, hi) if hi > lo else slice(0, 0), label=label)
        keep = (self.t >= start) & (self.t < end)
        idx = np.flatnonzero(keep)
        if idx.size == 0:
            return self.select(slice(0, 0), label=label)
        if idx[-1] - idx[0] + 1 == idx.size:
            return self.select(slice(int(idx[0]), int(idx[-1]) + 1), label=label)
        return self.select(keep, label=label)

    def select(self, mask_or_index: np.ndarray | slice, label: str | None = None) -> Recording:
        """Samples picked by a boolean mask, an index array or a slice (views, no copy)."""
        idx = mask_or_index
        return replace(
            self,
            t=self.t[idx],
            acc=self.acc[idx],
            gyr=self.gyr[idx],
            temp=None if self.temp is None else self.temp[idx],
            reference={k: v[idx] for k, v in self.reference.items()},
            label=self.label if label is None else label,
        )

    def with_label(self, label: str) -> Recording:
        return replace(self, label=label)

    def strictly_increasing(self) -> bool:
        """Whether t strictly increases (False with a NaN), one pass over it."""
        return bool(np.all(self.t[1:] > self.t[:-1]))


# A reading within this fraction of full scale counts as clipped: sensors clip at
# 32767/32768 of the range and files round to their last printed digit.
RANGE_MARGIN = 1e-3


@dataclass(frozen=True)
class RangeHit:
    """The first sample of a recording that reached the sensor's range.

    Attributes
    ----------
    sensor : ``"gyr"`` or ``"acc"``.
    axis : ``"x"``, ``"y"`` or ``"z"``.
    index : sample index in the recording.
    time : the sample's time, s (the recording's time base).
    value : the reading, SI (rad/s or m/s^2).
    full_scale : the range it reached, SI.
    """

    sensor: str
    axis: str
    index: int
    time: float
    value: float
    full_scale: float


def first_range_hit(
    rec: Recording, gyro_range: float | None = None, acc_range: float | None = None
) -> RangeHit | None:
    """The first sample whose gyro or accelerometer reading reached full scale.

    Parameters
    ----------
    rec : the samples.
    gyro_range : gyro full scale, rad/s, or None (not checked).
    acc_range : accelerometer full scale, m/s^2, or None (not checked).

    Returns
    -------
    The earliest RangeHit (gyro first on a tie), or None when every reading stays
    below full scale by more than RANGE_MARGIN of it. A clipped reading is not the
    sensor's response to the motion: anything integrated or averaged over it is wrong.
    """
    hits = []
    for sensor, data, full in (("gyr", rec.gyr, gyro_range), ("acc", rec.acc, acc_range)):
        if full is None or len(rec) == 0:
            continue
        limit = full * (1.0 - RANGE_MARGIN)
        low, high = float(data.min()), float(data.max())
        if -limit < low and high < limit:  # nothing near the range (false for a NaN)
            continue  # two reductions: no |data| copy, no row-wise any
        reached = np.abs(data) >= limit
        rows = np.flatnonzero(reached.any(axis=1))
        if rows.size:
            i = int(rows[0])
            j = int(np.flatnonzero(reached[i])[0])
            hits.append(RangeHit(sensor, "xyz"[j], i, float(rec.t[i]), float(data[i, j]), full))
    return min(hits, key=lambda h: h.index) if hits else None
