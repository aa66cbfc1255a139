"""The integral method's turns as motion between rests (docs/methods.md 2.6, estimator).

A rotation record is a rest, the turn, a rest, all in one orientation ("A up"). The
paper's equations hold over any stretch that holds the whole turn: the angle is the
integral of (rate - static reading) from rest to rest, and at every sample of the turn
the cross-axis rate is proportional to the on-axis one,

    w_c(t) - S_c = r_cA (w_A(t) - S_A),    r_cA = (delta_cA + M_cA) / (1 + M_AA).

The efficient estimator (setting ``turn_estimator = "regression"``) uses both: the
angle integrated over the turn's motion window (plus margins) only, so the rests' noise
does not enter it; each cross-axis integral read as r_cA times the on-axis one, r_cA
the least-squares slope of the cross-axis on the on-axis rate over both records of the
axis (where it holds and is the more precise); and the turns' static data (the rests, and
each cross-axis channel less its proportion of the turn) added to the static reading of
their orientation. The literal reading (``"whole_record"``) integrates every channel over
the whole record.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from calib_core.recording import Recording
from calib_core.stats import ChannelStats, channel_stats

TURN_ESTIMATORS = ("regression", "whole_record")

# Motion detection on the on-axis rate less the static reading, averaged over REST_S
# (at least REST_SAMPLES samples): a turn is where the average exceeds MOTION_SIGMA of
# its noise; the window then extends each way to where the average is within
# REST_EDGE_SIGMA of zero (the slow start and end of a turn, below any threshold but
# still turning) and MARGIN_AVERAGES averaging lengths beyond. A rest sample inside the
# window only adds noise; a turning sample outside it would bias the angle.
REST_S = 0.1
REST_SAMPLES = 5
MOTION_SIGMA = 8.0
REST_EDGE_SIGMA = 1.0
MARGIN_AVERAGES = 2
# The part of a record left out of the window must be at rest: its on-axis mean rate (less
# the static reading) within REST_TEST_SIGMA of its standard error, or the window takes it
# in (a hand-turned fixture settling slowly back into place, below any rate threshold, is
# still turning; imucal's annotated session turns 0.29 deg after its x turn's peak ends).
REST_TEST_SIGMA = 4.0
# The regression holds when the cross-axis rate less its proportion to the on-axis rate
# is white noise: its scatter within WOBBLE_RATIO of the channel's noise std (for white
# noise it is 1 within 1/sqrt(2N), N > 500). A turn whose axis wobbles (by hand: residual
# scatter 10-25 times the noise in imucal's sessions) breaks it; the wobble closes over
# the turn, so that channel's misalignment is read from its integral over the turn.
WOBBLE_RATIO = 1.5


def motion_window(
    gyr: np.ndarray,
    t: np.ndarray,
    axis: int,
    rest: np.ndarray,
    sigma: float,
    rest_std: float | None = None,
) -> slice:
    """The samples [start, stop) of one rotation record that hold the turn.

    Parameters
    ----------
    gyr : (N, 3) rad/s (despiked). t : (N,) s. axis : the rotation axis's channel.
    rest : (3,) static reading of the orientation, rad/s.
    sigma : white-noise std of the on-axis channel, rad/s (the record's, to find the turn).
    rest_std : the on-axis std at rest (the static record's), rad/s; None: the smaller
        of the record ends' own.

    Returns
    -------
    slice. The whole record when no sample stands out of the noise (nothing to narrow);
    an end that is not at rest (`_at_rest`) stays in.
    """
    n = len(t)
    step = float(np.median(np.diff(t))) if n > 1 else 0.0
    m = max(REST_SAMPLES, int(round(REST_S / step)) if step > 0 else REST_SAMPLES)
    if n < 3 * m or not sigma > 0:
        return slice(0, n)
    x = np.asarray(gyr[:, axis], dtype=float) - float(rest[axis])
    avg = np.convolve(x, np.ones(m) / m, mode="same")
    noise = sigma / math.sqrt(m)
    moving = np.flatnonzero(np.abs(avg) > MOTION_SIGMA * noise)
    if moving.size == 0:
        return slice(0, n)
    quiet = np.abs(avg) <= REST_EDGE_SIGMA * noise
    before = np.flatnonzero(quiet[: moving[0]])
    after = np.flatnonzero(quiet[moving[-1] :])
    start = before[-1] if before.size else 0
    stop = moving[-1] + after[0] + 1 if after.size else n
    margin = MARGIN_AVERAGES * m
    start, stop = max(int(start) - margin, 0), min(int(stop) + margin, n)
    if rest_std is None:
        ends = [x[:start], x[stop:]]
        rest_std = min((float(e.std(ddof=1)) for e in ends if len(e) > 1), default=0.0)
    if not _at_rest(x[:start], rest_std):
        start = 0
    if not _at_rest(x[stop:], rest_std):
        stop = n
    return slice(start, stop)


def _at_rest(part: np.ndarray, rest_std: float) -> bool:
    """Whether a record's end (rate less the static reading) is at rest: its scatter
    within WOBBLE_RATIO of the rest's std (a hand holding the fixture shakes it) and its
    mean zero within REST_TEST_SIGMA standard errors (a slow creep). An end of one sample
    cannot be tested and is taken in; an empty one is at rest."""
    if len(part) == 0:
        return True
    if len(part) < 2:
        return False
    if part.std(ddof=1) > WOBBLE_RATIO * rest_std:
        return False
    return abs(part.mean()) <= REST_TEST_SIGMA * rest_std / math.sqrt(len(part))


def face_rest_stats(
    faces: Mapping[str, Recording],
    rests: Mapping[str, list[np.ndarray]],
) -> dict[str, ChannelStats]:
    """Gyro statistics per static orientation: its face's samples with the static data
    the turns made in that orientation give (label "A_up" for the turns about A).

    Parameters
    ----------
    faces : label -> the static face's Recording.
    rests : label -> (N_k, 3) static samples from the turns in that orientation, NaN
        where a channel has none (`integral.turn_rests`; an orientation without is absent).

    Returns
    -------
    label -> ChannelStats of the samples pooled per channel (channel_stats: its n_eff
    counts the autocorrelation; n is the fewest samples of a channel).
    """
    out = {}
    for label, rec in faces.items():
        extra = [r for r in rests.get(label, []) if len(r)]
        out[label] = pooled_stats([rec.gyr, *extra]) if extra else channel_stats(rec.gyr)
    return out


def pooled_stats(parts: list[np.ndarray]) -> ChannelStats:
    """`channel_stats` of (N_k, 3) arrays joined, per channel over its samples that are
    not NaN (n: the fewest of a channel). ValueError when a channel has fewer than 2."""
    pooled = np.concatenate(parts)
    cols = [channel_stats(c[~np.isnan(c)][:, None]) for c in pooled.T]
    fields = [np.concatenate([getattr(c, f) for c in cols]) for f in ("mean", "std", "sem")]
    n_eff = np.concatenate([c.n_eff for c in cols])
    return ChannelStats(*fields, n_eff, min(c.n for c in cols))


def cross_axis_ratios(
    records: list[np.ndarray], axis: int, sigma: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares slopes r_cA of each channel on the on-axis rate, with intercept,
    over the records of one axis (ccw and cw: one orientation, one static reading).

    Parameters
    ----------
    records : the (N_k, 3) despiked gyro records of the turns about `axis`, rad/s.
    axis : the rotation axis's channel. sigma : (3,) white-noise std per channel, rad/s.

    Returns
    -------
    ratio (3,) (1 at `axis`); its standard uncertainty (3,) (0 at `axis`), from the
    larger of sigma and the residual scatter; whether the regression holds per channel
    (3,) bool (residual scatter within WOBBLE_RATIO of sigma; True at `axis`). The
    on-axis noise in the regressor shrinks the slope by sigma_A^2 / var(w_A), under 1e-4
    of it for a turn at 1 rad/s and a noise of 1e-2 rad/s: left alone.
    """
    gyr = np.concatenate(records)
    x = gyr[:, axis] - gyr[:, axis].mean()
    y = gyr - gyr.mean(axis=0)
    sxx = float(x @ x)
    ratio = (x @ y) / sxx
    resid = y - np.outer(x, ratio)
    scatter = np.sqrt(np.sum(resid**2, axis=0) / max(len(x) - 2, 1))
    sigma = np.asarray(sigma, dtype=float)
    std = np.maximum(sigma, scatter) / math.sqrt(sxx)
    holds = scatter <= WOBBLE_RATIO * sigma
    ratio[axis], std[axis], holds[axis] = 1.0, 0.0, True
    return ratio, std, holds
