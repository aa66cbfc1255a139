"""Static bias and noise from one long static record (docs/methods.md 2.5), in chunks.

The record arrives in chunks (`solve_static_bias_stream`); one in memory is the one-chunk
case (`solve_static_bias`): one science whatever the record's size. Two passes over the
chunks: the first gives the count, mean and std of every channel (skipped when the caller
computed them while reading the file) and the median time step; the second applies the
n-sigma rule with those, keeps the kept samples' moments and streams the outlier-filled
record into the Allan deviation (`calib_core.streamed`): all channels in one pass over
the chunks, or, from a store that reads one channel alone (`channel_chunks`), a pass per
channel, each with the whole phase memory to itself. With a label the solve also makes
the motion check (`calib_core.preprocess.motion.StreamedMotion`, on the samples before
the fill, as the in-memory check sees them). A caller's first pass (`FirstPass.empty()`,
pushed while the file is read) computes its windows' statistics on the caller's helper
(`Execution`), at the window width of the first chunk's time steps; when that is the
record's width (`StreamedMotion.settle`), the second pass has no motion work. Otherwise
(a short record, a first chunk whose rate is not the record's) the second pass computes
the windows.

Frame of the Earth-rate correction: a level fixture, body z up, body x pointing
at `heading_deg` (clockwise from true North seen from above), y completing the
right-handed frame (so y points at heading - 90 deg). In that frame the Earth
rate is

    w_ie = Omega [cos(lat) cos(hdg), cos(lat) sin(hdg), sin(lat)]

which a FOG/RLG-grade gyro sees (Omega = 15.04 deg/h) and a MEMS gyro does not.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TypedDict, Unpack

import numpy as np

from calib_core.calibration import Calibration
from calib_core.distributions import norm_sf
from calib_core.earth import EARTH_RATE
from calib_core.noise import NOISE_TERMS, archived_terms, choose_noise_fit, mean_uncertainty
from calib_core.params import AXES
from calib_core.preprocess.motion import StreamedMotion, motion_check_of, streamed_smallest_steps
from calib_core.preprocess.replaced import replaced_check
from calib_core.recording import Recording
from calib_core.streamed import (
    IN_LINE,
    Execution,
    MedianStep,
    Moments,
    Pending,
    SigmaClipFill,
    StreamedAllan,
    joined_allan,
)
from calib_core.units import STANDARD_GRAVITY

MIN_DURATION_S = 3600.0  # docs/methods.md 2.5: >= 60 min static
BIAS_UNCERTAINTY_RULE = (
    "u(bias) = Allan deviation of the noise model N^2/tau + (0.664 B)^2 + K^2 tau/3 at "
    "tau = record length, B and K kept where the curve supports them (3 standard errors "
    "above 0): exact for white noise (= std/sqrt(n)) and for rate random walk (std of the "
    "record mean about the starting bias)"
)


def earth_rate_level_frame(latitude_deg: float, heading_deg: float) -> np.ndarray:
    """Earth rate seen by a level z-up fixture (frame in the module docstring), rad/s, (3,)."""
    lat, hdg = math.radians(latitude_deg), math.radians(heading_deg)
    return EARTH_RATE * np.array(
        [math.cos(lat) * math.cos(hdg), math.cos(lat) * math.sin(hdg), math.sin(lat)]
    )


def _up_vector(up_axis: str) -> np.ndarray:
    if len(up_axis) != 2 or up_axis[0] not in "+-" or up_axis[1] not in AXES:
        raise ValueError(f"up_axis must be one of +x, -x, +y, -y, +z, -z, got {up_axis!r}")
    e = np.zeros(3)
    e[AXES.index(up_axis[1])] = 1.0 if up_axis[0] == "+" else -1.0
    return e


def sensor_statistics(x: np.ndarray, rate_hz: float, n_sigma: float, taus) -> tuple:
    """mean, std, outlier counts, Allan result, noise parameters, u(mean), fit misfits and
    warnings (None or text, per channel) of one sensor's (N, 3) samples in memory: the
    solve's statistics (`_Group`) of one chunk, then its noise fits (`choose_noise_fit`)."""
    total = Moments(x.shape[1])
    total.push(x)
    allan = StreamedAllan(
        rate_hz, x.shape[0], x.shape[1], taus=taus, offset=total.mean, execution=_whole(x)
    )
    group = _Group(total, n_sigma, allan)
    group.push(x)
    group.flush()
    mean, std, counts, allan = _statistics([group])
    return (mean, std, counts, allan, *_noise_stats(allan, std, x.shape[0], rate_hz))


def _whole(x: np.ndarray) -> Execution:
    """In line, the whole Allan phase of the N samples x in one buffer (a record in memory)."""
    return Execution(memory_rows=x.shape[0] + 1)


def _noise_stats(allan, std: np.ndarray, n: int, rate_hz: float) -> tuple:
    """noise parameters, u(mean), fit misfits and warnings (None or text, per channel) of
    one sensor's Allan result (`choose_noise_fit`)."""
    duration = n / rate_hz
    chosen = [choose_noise_fit(allan.column(c)) for c in range(3)]
    noise = [c[0] for c in chosen]
    misfits = [c[1] for c in chosen]
    warnings = [c[2] for c in chosen]
    sem_white = std / math.sqrt(n)
    u = np.array([mean_uncertainty(allan.column(c), duration) for c in range(3)])
    # A fit that found no noise at all (constant data) still has the white-noise floor.
    u = np.where(np.isfinite(u) & (u > 0), u, sem_white)
    return noise, u, misfits, warnings


def earth_rate_removed(
    where: str,
    n: int,
    n_sigma: float,
    remove_earth_rate: bool,
    latitude_deg: float | None,
    heading_deg: float | None,
    up_axis: str | None,
) -> np.ndarray:
    """Check the settings; the Earth rate to remove from the gyro means, rad/s (zeros if not)."""
    if n < 16:
        raise ValueError(f"static bias ({where}): need >= 16 samples, got {n}")
    if n_sigma <= 0:
        raise ValueError(f"static bias: n_sigma must be > 0, got {n_sigma}")
    earth = np.zeros(3)
    if remove_earth_rate:
        if latitude_deg is None or heading_deg is None:
            raise ValueError(
                f"static bias ({where}): remove_earth_rate needs latitude_deg and heading_deg, "
                f"got latitude_deg={latitude_deg!r}, heading_deg={heading_deg!r}"
            )
        if up_axis not in (None, "+z"):
            raise ValueError(
                f"static bias ({where}): the Earth-rate correction is defined for the level "
                f"z-up fixture, got up_axis={up_axis!r}"
            )
        earth = earth_rate_level_frame(latitude_deg, heading_deg)
    return earth


class StaticBiasSettings(TypedDict, total=False):
    """The settings of a static-bias solve (`solve_static_bias`), in memory or streamed;
    their defaults are `solve_static_bias_stream`'s."""

    latitude_deg: float | None
    heading_deg: float | None
    remove_earth_rate: bool
    n_sigma: float
    up_axis: str | None
    gravity: float
    taus: str | np.ndarray


def solve_static_bias(rec: Recording, **settings: Unpack[StaticBiasSettings]) -> Calibration:
    """Gyro bias and noise (and accelerometer bias if the orientation is known): the one-chunk
    case of `solve_static_bias_stream`.

    Parameters
    ----------
    rec : one static Recording, ideally >= 60 min (a warning is added if shorter).
    settings : `StaticBiasSettings`, each optional:
    latitude_deg, heading_deg : site latitude and fixture heading (module docstring
        frame), degrees; needed when `remove_earth_rate`.
    remove_earth_rate : subtract the Earth-rate projection from the gyro means
        (FOG/RLG-grade units); only for the level z-up fixture (default: not).
    n_sigma : outlier rule (default 3); rejected samples are left out of mean and std and
        interpolated over for the Allan deviation.
    up_axis : body axis pointing up ("+z", "-x", ...); if given, acc.bias.* is the
        mean minus gravity along that axis.
    gravity : local gravity, m/s^2 (default: standard gravity).
    taus : cluster times of the Allan deviation ("octave" (default), "log" or seconds).

    Returns
    -------
    Calibration "static_bias" with gyr.bias.* and gyr.noise.* (std of one sample,
    rad/s), acc.noise.* (m/s^2), acc.bias.* when `up_axis` is given. Bias
    uncertainties follow BIAS_UNCERTAINTY_RULE (white-noise std/sqrt(n) would be
    far too small under bias instability and random walk). `info` holds the Allan
    deviations (lists), the noise parameters of every channel, outlier counts and
    the Earth rate removed.
    """
    t = np.asarray(rec.t, dtype=float)
    both = np.hstack([np.asarray(rec.gyr, dtype=float), np.asarray(rec.acc, dtype=float)])
    chunk = (t, both[:, :3], both[:, 3:])  # views of one array: the first pass takes it
    return solve_static_bias_stream(
        lambda: iter([chunk]),
        label=rec.label or "record",
        first=FirstPass.of(t, both),
        execution=_whole(both),
        **settings,
    )


def static_bias_calibration(
    stats: dict[str, tuple],
    n: int,
    rate_hz: float,
    label: str,
    earth: np.ndarray,
    *,
    n_sigma: float,
    latitude_deg: float | None,
    heading_deg: float | None,
    up_axis: str | None,
    gravity: float,
) -> Calibration:
    """The static-bias Calibration from each sensor's statistics (`_statistics`).

    stats : {"gyr": ..., "acc": ...}, each (mean (3,), std (3,) ddof 1, outlier counts (3,),
        AllanResult (K, 3)) of the kept samples (the n-sigma rule).
    n : samples; rate_hz : median sample rate, Hz; label : the record's label;
    earth : Earth rate removed from the gyro means, rad/s (3,).
    """
    cal = Calibration(procedure="static_bias", gravity=float(gravity))
    duration = n / rate_hz  # samples x period (t[-1] - t[0] is one period short)
    if duration < MIN_DURATION_S - 0.5 / rate_hz:  # half a sample of rounding slack
        cal.warnings.append(
            f"static record is {duration / 60:.1f} min long; the procedure asks for >= 60 min"
        )
    info: dict = {
        "n_samples": n,
        "duration_s": duration,
        "sample_rate_hz": rate_hz,
        "n_sigma": n_sigma,
        "bias_uncertainty_rule": BIAS_UNCERTAINTY_RULE,
        "earth_rate_removed": earth.tolist(),
        "latitude_deg": latitude_deg,
        "heading_deg": heading_deg,
        "allan": {},
        "noise_parameters": {},
        "outliers": {},
    }
    checks: list[dict] = []
    references = {"gyr": earth, "acc": None if up_axis is None else gravity * _up_vector(up_axis)}
    for sensor, reference in references.items():
        mean, std, counts, allan = stats[sensor]
        noise, u, misfits, warns = _noise_stats(allan, std, n, rate_hz)
        cal.warnings += [f"{sensor}.{a}: {w}" for a, w in zip(AXES, warns, strict=True) if w]
        worst = [m["misfit_max"] for m in misfits if m["misfit_max"] is not None]
        # A scalar: it goes into the solve step's record (statistics).
        info[f"{sensor}_noise_fit_misfit_max"] = max(worst) if worst else None
        for i, a in enumerate(AXES):
            cal.add(f"{sensor}.noise.{a}", std[i])
            if reference is not None:
                cal.add(f"{sensor}.bias.{a}", mean[i] - reference[i], u[i])
        info["allan"][sensor] = allan.to_dict()
        # A stuck channel's Allan deviation is the rounding of its constant value.
        varies = std > 64 * np.finfo(float).eps * np.abs(mean)
        terms = [
            archived_terms(p, allan.column(c), warns[c] is None, bool(varies[c]))
            for c, p in enumerate(noise)
        ]
        info["noise_parameters"][sensor] = [
            {**p.to_dict(), **m, **t} for p, m, t in zip(noise, misfits, terms, strict=True)
        ]
        checks += _undetermined_checks(sensor, terms)
        info["outliers"][sensor] = counts.tolist()
        if counts.max() > 0.01 * n:
            cal.warnings.append(
                f"{sensor}: {counts.max()} samples ({100 * counts.max() / n:.1f} %) outside "
                f"{n_sigma} sigma in one channel; expected ~0.3 % for Gaussian noise"
            )
    cal.info.update(info)
    clipped = {
        f"{sensor}.{a}": int(n)
        for sensor, counts in info["outliers"].items()
        for a, n in zip(AXES, counts, strict=True)
    }
    checks.append(
        replaced_check(
            "static_bias", label, clipped, 6 * n, 2.0 * float(norm_sf(n_sigma)), "left out"
        )
    )
    cal.info.setdefault("replaced_samples", {})["static_bias"] = clipped
    cal.info.setdefault("solver_checks", []).extend(checks)
    return cal


def _undetermined_checks(sensor: str, terms: list[dict]) -> list[dict]:
    """A ``model:noise:<sensor>.<axis>`` check for each channel with a noise term the
    record does not determine (archived as None, never as 0)."""
    out = []
    for a, t in zip(AXES, terms, strict=True):
        missing = [k for k in NOISE_TERMS if t[k] is None]
        if missing:
            out.append(
                {
                    "name": f"model:noise:{sensor}.{a}",
                    "value": None,
                    "limit": None,
                    "passed": False,
                    "detail": "; ".join(f"{k}: {t[f'{k}_method']}" for k in missing),
                }
            )
    return out


# One chunk: t (n,) s, gyr (n, 3) rad/s, acc (n, 3) m/s^2.
Chunk = tuple[np.ndarray, np.ndarray, np.ndarray]
SENSORS = {"gyr": slice(0, 3), "acc": slice(3, 6)}  # columns of [gyr | acc]


@dataclass
class FirstPass:
    """What the first pass over a static record keeps: moments of [gyr | acc], the
    median time step (`MedianStep`), the first time (s), the smallest and largest
    value of each channel of [gyr | acc] (the range check) and the motion check's windows.

    The motion windows (`motion`: a `StreamedMotion` whose record length is not known
    yet) and, after the first chunk, the moments, steps and extremes are computed on the
    `execution`'s helper (in line without one), one chunk at a time (the next push waits
    for the previous chunk's; `close`, `n` and `t_last` for the last): NumPy releases the
    GIL, so the reading goes on meanwhile.
    Their width is a long record's at the first chunk's median rate; `settled_motion`
    says at the end whether it is the record's. `motion` None: not computed (`watch_motion`
    false, or the first chunk could not set a width: the solve's pass computes them).
    """

    moments: Moments
    step: MedianStep
    t_first: float | None = None
    low: np.ndarray | None = None
    high: np.ndarray | None = None
    motion: StreamedMotion | None = None
    watch_motion: bool = True
    execution: Execution = field(default=IN_LINE, repr=False)
    pending: Pending | None = field(default=None, repr=False)

    rate_hz: float | None = None  # known whole (`of`); else from `step`

    @classmethod
    def empty(cls, watch_motion: bool = True, execution: Execution = IN_LINE) -> FirstPass:
        return cls(Moments(6), MedianStep(), watch_motion=watch_motion, execution=execution)

    @classmethod
    def of(cls, t: np.ndarray, both: np.ndarray) -> FirstPass:
        """The first pass of a record in memory, times t (N,) s and [gyr | acc] (N, 6): its
        moments and extremes, its median rate from the whole time array (as
        `Recording.sample_rate`, however many distinct steps it has); no motion windows."""
        out = cls(Moments(6), MedianStep(), watch_motion=False)
        if both.shape[0]:
            out.moments.push(both)
            out.t_first, out.low, out.high = float(t[0]), both.min(axis=0), both.max(axis=0)
        if t.size >= 2:
            out.rate_hz = float(1.0 / np.median(np.diff(t)))
            out.step.last = float(t[-1])
        return out

    def rate(self) -> float:
        """The record's median sample rate, Hz."""
        return self.rate_hz if self.rate_hz is not None else 1.0 / self.step.median()

    def push(self, chunk: Chunk) -> None:
        t, gyr, acc = chunk
        both = _joined(gyr, acc)
        if both.shape[0] == 0:
            return
        self.close()  # one chunk pending at a time: bounded memory
        if self.low is None:  # the first chunk, in line: it sets the windows' width
            self.t_first = float(t[0])
            self._take(t, both)
            self.motion = _provisional_motion(t) if self.watch_motion else None
            if self.motion is not None:
                self.pending = self.execution.run(self.motion.push, t, both)
        elif self.motion is not None:  # beside the reading of the next chunk
            self.pending = self.execution.run(self._take_and_watch, t, both)
        else:
            self._take(t, both)

    def _take(self, t: np.ndarray, both: np.ndarray) -> None:
        """Moments, time steps and extremes of a chunk."""
        self.moments.push(both)
        self.step.push(t)
        low, high = both.min(axis=0), both.max(axis=0)
        if self.low is None:
            self.low, self.high = low, high
        else:
            np.minimum(self.low, low, out=self.low)
            np.maximum(self.high, high, out=self.high)

    def _take_and_watch(self, t: np.ndarray, both: np.ndarray) -> None:
        self._take(t, both)
        self.motion.push(t, both)

    def close(self) -> None:
        """Wait for the last chunk's motion windows (a failure in them is raised here).
        Readers call it when the record ends; the solve calls it anyway."""
        pending, self.pending = self.pending, None
        if pending is not None:
            pending.result()

    def settled_motion(self, n: int, rate: float) -> StreamedMotion | None:
        """The motion windows of this pass if they are those of the record of `n` samples
        at median `rate` Hz (`StreamedMotion.settle`), else None (compute them again)."""
        self.close()
        if self.motion is None or not self.motion.settle(n, rate):
            return None
        return self.motion

    @property
    def t_last(self) -> float | None:
        """The last time pushed, s."""
        self.close()
        return self.step.last

    @property
    def n(self) -> int:
        self.close()
        return int(self.moments.n[0])


def _provisional_motion(t: np.ndarray) -> StreamedMotion | None:
    """Motion windows at a long record's width for the median rate of the first chunk's
    times t (s); None when they cannot be set from it: fewer than two times, or a window
    longer than the chunk (its rows carried over would grow past a chunk: a small memory
    limit, or a first chunk whose steps are far shorter than the record's)."""
    if t.shape[0] < 2:
        return None
    step = float(np.median(np.diff(t)))
    if not (math.isfinite(step) and step > 0.0):
        return None
    motion = StreamedMotion(None, 1.0 / step)
    return motion if motion.width <= t.shape[0] else None


def _joined(gyr: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """[gyr | acc] (n, 6): without a copy when the reader made them views of one array."""
    both = gyr.base if gyr.base is not None and gyr.base is acc.base else None
    if both is None or both.shape != (gyr.shape[0], 6):
        return np.hstack([gyr, acc])
    return both


def first_pass(chunks: Iterable[Chunk]) -> FirstPass:
    """Moments and time steps of a stream of chunks (no motion windows: the solve's
    second pass computes them, on the chunks it is given)."""
    out = FirstPass.empty(watch_motion=False)
    for chunk in chunks:
        out.push(chunk)
    return out


def solve_static_bias_stream(
    chunks: Callable[[], Iterator[Chunk]],
    *,
    label: str = "record",
    first: FirstPass | None = None,
    latitude_deg: float | None = None,
    heading_deg: float | None = None,
    remove_earth_rate: bool = False,
    n_sigma: float = 3.0,
    up_axis: str | None = None,
    gravity: float = STANDARD_GRAVITY,
    taus: str | np.ndarray = "octave",
    motion_label: str | None = None,
    channel_chunks: Callable[[int], Iterator[np.ndarray]] | None = None,
    execution: Execution = IN_LINE,
) -> Calibration:
    """`calib_core.solvers.static_bias.solve_static_bias` on a streamed record.

    Parameters
    ----------
    chunks : called once per pass, a fresh iterator of (t, gyr, acc) chunks, in order (t
        may be None when `first` is given and `motion_label` is None: the second pass
        needs no time).
    label : the record's label (checks name it).
    first : the first pass's statistics of these chunks if the caller has them (else one
        more pass); its motion windows are used when they are the record's
        (`FirstPass.settled_motion`), else the second pass computes them.
    motion_label : with a label, the record's motion check (``motion:<label>``) among the
        Calibration's ``solver_checks``; None: no motion check.
    channel_chunks : channel_chunks(c) a fresh iterator over channel c of [gyr | acc] alone,
        (n, 1) chunks in order: the channels are then solved one after the other, each
        in a pass of its own (a column store reads one column for it; each channel's
        phase gets the whole `memory_rows`). None: one pass over `chunks` for all.
    execution : what the solve runs on (`calib_core.streamed.Execution`): each Allan
        deviation's phase memory and history (of a sensor's channels, or of one channel
        with `channel_chunks`, whose phases take the workspace in turn); with a helper,
        one sensor's channels and a chunk's motion windows are computed on it beside the
        other's (one pass), or half of each channel's Allan sums (`channel_chunks`). The
        numbers do not depend on it.
    Other parameters as `solve_static_bias`.

    Returns
    -------
    The same Calibration as `solve_static_bias` on the whole record, to rounding.
    """
    first = first if first is not None else first_pass(chunks())
    n = first.n
    earth = earth_rate_removed(
        label, n, n_sigma, remove_earth_rate, latitude_deg, heading_deg, up_axis
    )
    rate_hz = first.rate()

    def group(cols: slice, on: Execution) -> _Group:
        """The n-sigma rule and the Allan sums of the channels `cols` of [gyr | acc]."""
        channels, offset = cols.stop - cols.start, first.moments.mean[cols]
        allan = StreamedAllan(rate_hz, n, channels, taus=taus, offset=offset, execution=on)
        return _Group(first.moments.columns(cols), n_sigma, allan)

    motion, again = None, False
    if motion_label is not None:
        motion = first.settled_motion(n, rate_hz)
        again = motion is None  # not the first pass's: a pass computes the windows
        motion = StreamedMotion(n, rate_hz) if again else motion
    if channel_chunks is None:
        stats = _one_pass(chunks, group, execution, motion if again else None)
    else:
        if again:  # the windows from a pass of their own
            _one_pass(chunks, group, execution, motion, sensors={})
        stats = _channel_passes(channel_chunks, group, execution)
    cal = static_bias_calibration(
        stats,
        n,
        rate_hz,
        label,
        earth,
        n_sigma=n_sigma,
        latitude_deg=latitude_deg,
        heading_deg=heading_deg,
        up_axis=up_axis,
        gravity=gravity,
    )
    if motion is not None:
        check = motion_check_of(motion_label, motion.result(lambda cols: _steps(chunks, cols)))
        if check is not None:
            cal.info.setdefault("solver_checks", []).append(check)
    return cal


def _one_pass(
    chunks: Callable[[], Iterator[Chunk]],
    group: Callable[[slice, Execution], _Group],
    execution: Execution,
    motion: StreamedMotion | None,
    sensors: dict[str, slice] = SENSORS,
) -> dict[str, tuple]:
    """The statistics (`_statistics`) of each of `sensors` from one pass over `chunks`, a
    sensor's channels as a group (neither's numbers depend on the other's), with the
    motion windows when `motion` is given (`sensors` empty: the windows alone).

    With a helper, a chunk's motion windows and the first sensor's group run on it
    beside the other sensor's (NumPy and the compiled sums release the GIL; none writes
    the chunk), one chunk at a time, in order."""
    own = dataclasses.replace(execution, submit=None, workspace=None)
    groups = [group(cols, own) for cols in sensors.values()]
    pending = None
    for t, gyr, acc in chunks():
        both = _joined(gyr, acc)
        if motion is not None:  # before the fill: the samples the in-memory check sees
            if pending is not None:
                pending.result()
            pending = execution.run(motion.push, t, both)
        parts = [(g, both[:, cols]) for g, cols in zip(groups, sensors.values(), strict=True)]
        beside = [execution.run(g.push, x) for g, x in parts[:1]]
        for g, x in parts[1:]:
            g.push(x)
        for job in beside:
            job.result()
    for g in groups:
        g.flush()
    if pending is not None:
        pending.result()
    return {sensor: _statistics([g]) for sensor, g in zip(sensors, groups, strict=True)}


def _channel_passes(
    channel_chunks: Callable[[int], Iterator[np.ndarray]],
    group: Callable[[slice, Execution], _Group],
    execution: Execution,
) -> dict[str, tuple]:
    """Each sensor's statistics from a pass per channel, one channel after the other
    (half of each one's Allan sums on the execution's helper, when it has one; their
    phases in its workspace in turn)."""
    stats = {}
    for sensor, cols in SENSORS.items():
        done = []
        for c in range(cols.start, cols.stop):
            g = group(slice(c, c + 1), execution)
            for x in channel_chunks(c):
                g.push(x)
            g.flush()
            done.append(g)
        stats[sensor] = _statistics(done)
    return stats


class _Group:
    """Channels through the n-sigma rule and the Allan sums, chunk by chunk."""

    def __init__(self, total: Moments, n_sigma: float, allan: StreamedAllan):
        self.allan = allan
        self.clip = SigmaClipFill(total.mean, total.std(), n_sigma, total=total)

    def push(self, x: np.ndarray) -> None:
        """The channels' next samples (n, C)."""
        self.allan.push(self.clip.push(x))

    def flush(self) -> None:
        """The last samples (held back by the fill); the phase's memory let go."""
        self.allan.push(self.clip.flush())
        self.allan.release()


def _statistics(groups: list[_Group]) -> tuple:
    """(kept mean, kept std (ddof 1), rejected count, AllanResult) of the channels of
    `groups`, side by side in their order."""
    kept = [g.clip.kept for g in groups]
    return (
        np.concatenate([k.mean for k in kept]),
        np.concatenate([k.std(ddof=1) for k in kept]),
        np.concatenate([g.clip.rejected for g in groups]),
        joined_allan([g.allan for g in groups]),
    )


def _steps(chunks: Callable[[], Iterator[Chunk]], cols: np.ndarray) -> np.ndarray:
    """The record's smallest steps of the channels `cols` of [gyr | acc] (one more pass)."""
    return streamed_smallest_steps(_joined(g, a)[:, cols] for _, g, a in chunks())
