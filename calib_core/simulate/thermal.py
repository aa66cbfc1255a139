"""Thermal compensation, the simulator: temperature-dependent IMUs, campaigns, soaks, drift.

The truth of a parameter p at temperature T (deg C) is a polynomial around T_ref
plus, when the unit is cooling, a hysteresis offset:

    p(T) = p_0 + sum_k c_k (T - T_ref)^k  -/+ h / 2   (heating -, cooling +)

so h is "cooling minus heating" at equal temperature and the polynomial is the
mid-line, the convention of calib_core.thermal. Re-calibration histories add a
slow linear drift per day to the parameters at T_ref.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from calib_core import params
from calib_core.recording import Recording
from calib_core.simulate.lab_run import SimulatedRun, TrueErrors, six_position_integral_run
from calib_core.solvers.six_position import axis_vector
from calib_core.thermal import COOLING, HEATING
from calib_core.units import DEG, STANDARD_GRAVITY

# Typical MEMS thermal sensitivities (|c_k| drawn uniform in [low, high], random sign),
# SI per deg C^k. Gyro bias ~0.01 deg/s/degC, accel bias ~0.4 mg/degC, scale ~100 ppm/degC.
THERMAL_RANGES: dict[str, tuple[tuple[float, float], ...]] = {
    "acc.bias": ((2e-3, 6e-3), (2e-5, 6e-5), (4e-7, 1.2e-6)),
    "gyr.bias": ((0.005 * DEG, 0.015 * DEG), (5e-5 * DEG, 1.5e-4 * DEG), (1e-6 * DEG, 3e-6 * DEG)),
    "acc.scale": ((5e-5, 1.5e-4), (1e-6, 3e-6), (2e-8, 6e-8)),
    "gyr.scale": ((5e-5, 1.5e-4), (1e-6, 3e-6), (2e-8, 6e-8)),
}


def set_parameters(errors: TrueErrors, values: Mapping[str, float]) -> TrueErrors:
    """A copy of `errors` with the named parameters (canonical names, SI) replaced."""
    acc_b, gyr_b = errors.acc_bias.copy(), errors.gyr_bias.copy()
    acc_M, gyr_M, G = errors.acc_M.copy(), errors.gyr_M.copy(), errors.gsens.copy()  # noqa: N806
    for name, value in values.items():
        sensor, kind, axes = params.validate(name).split(".")
        i = params.AXIS_INDEX[axes[0]]
        j = params.AXIS_INDEX[axes[-1]]
        if kind == "bias":
            (acc_b if sensor == "acc" else gyr_b)[i] = value
        elif kind in ("scale", "misalign"):
            (acc_M if sensor == "acc" else gyr_M)[i, j] = value
        elif kind == "gsens":
            G[i, j] = value
        else:
            raise ValueError(f"the simulator has no {kind} parameters: {name}")
    return replace(errors, acc_bias=acc_b, gyr_bias=gyr_b, acc_M=acc_M, gyr_M=gyr_M, gsens=G)


@dataclass
class ThermalTruth:
    """A simulated unit whose parameters depend on temperature.

    Attributes
    ----------
    base : the error model at t_ref (heating / cooling mid-line).
    t_ref : deg C.
    coefficients : name -> (c_1, ..., c_k), SI per deg C^k, of (T - t_ref)^k.
    hysteresis : name -> h, cooling minus heating at equal temperature, SI.
    """

    base: TrueErrors
    t_ref: float = 25.0
    coefficients: dict[str, np.ndarray] = field(default_factory=dict)
    hysteresis: dict[str, float] = field(default_factory=dict)

    def order(self, name: str) -> int:
        """True polynomial order of a parameter (0 when it does not depend on T)."""
        return int(len(self.coefficients.get(name, ())))

    def polynomial(self, name: str) -> np.ndarray:
        """(order + 1,) true c_0 .. c_k of the mid-line around t_ref."""
        c0 = self.base.parameters()[name]
        return np.concatenate([[c0], np.asarray(self.coefficients.get(name, ()), dtype=float)])

    def value(self, name: str, temperature: np.ndarray | float, direction: str = "") -> np.ndarray:
        """p(T) of one parameter; direction "heating" / "cooling" adds -h/2 / +h/2."""
        v = np.polynomial.polynomial.polyval(
            np.asarray(temperature, dtype=float) - self.t_ref, self.polynomial(name)
        )
        h = self.hysteresis.get(name, 0.0)
        return v + {HEATING: -0.5 * h, COOLING: 0.5 * h}.get(direction, 0.0)

    def errors_at(self, temperature: float, direction: str = "") -> TrueErrors:
        """The unit's error model at one temperature."""
        names = set(self.coefficients) | set(self.hysteresis)
        return set_parameters(
            self.base, {n: float(self.value(n, temperature, direction)) for n in names}
        )


def random_thermal_truth(
    rng: np.random.Generator,
    orders: Mapping[str, int] | None = None,
    *,
    t_ref: float = 25.0,
    hysteresis: Mapping[str, float] | None = None,
    base: TrueErrors | None = None,
) -> ThermalTruth:
    """Draw a unit with polynomial thermal behaviour.

    orders : parameter family ("acc.bias", "gyr.bias", "acc.scale", "gyr.scale")
        -> polynomial order for its three axes; default biases 2, scales 1.
    hysteresis : parameter name -> h (cooling minus heating), SI.
    base : the model at t_ref; default lab_run.random_errors.
    """
    from calib_core.simulate.lab_run import random_errors

    orders = dict(orders or {"acc.bias": 2, "gyr.bias": 2, "acc.scale": 1, "gyr.scale": 1})
    coefficients: dict[str, np.ndarray] = {}
    for family, order in orders.items():
        ranges = THERMAL_RANGES[family]
        if not 0 <= order <= len(ranges):
            raise ValueError(f"{family}: order {order} not in 0 .. {len(ranges)}")
        for a in params.AXES:
            if order:
                low = np.array([r[0] for r in ranges[:order]])
                high = np.array([r[1] for r in ranges[:order]])
                c = rng.uniform(low, high) * rng.choice([-1.0, 1.0], order)
                coefficients[f"{family}.{a}"] = c
    return ThermalTruth(
        base=base if base is not None else random_errors(rng),
        t_ref=t_ref,
        coefficients=coefficients,
        hysteresis=dict(hysteresis or {}),
    )


@dataclass
class CampaignRun:
    """One lab run of a thermal campaign."""

    temperature: float  # deg C, chamber set point (the unit's temperature once soaked)
    direction: str  # "heating" or "cooling"
    run: SimulatedRun


def thermal_campaign(
    truth: ThermalTruth,
    rng: np.random.Generator,
    temperatures: Sequence[float] = (-10.0, 0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0),
    *,
    cooling: bool = False,
    **run_kwargs: float,
) -> list[CampaignRun]:
    """Six-position + integral runs at each temperature point, heating up (then cooling down).

    With `cooling`, the points are run upwards and then downwards again
    (excluding the top point twice), each with the error model of its direction.
    run_kwargs go to six_position_integral_run (static_s, rate_hz, ...).
    """
    temps = [float(t) for t in sorted(temperatures)]
    plan = [(t, HEATING) for t in temps]
    if cooling:
        plan += [(t, COOLING) for t in reversed(temps[:-1])]
    out = []
    for temp, direction in plan:
        errors = truth.errors_at(temp, direction)
        run = six_position_integral_run(errors, rng, temp_c=temp, **run_kwargs)
        run.settings["direction"] = direction
        out.append(CampaignRun(temp, direction, run))
    return out


def soak_sweep(
    truth: ThermalTruth,
    rng: np.random.Generator,
    *,
    t_low: float = -10.0,
    t_high: float = 60.0,
    rate_c_per_min: float = 1.0,
    rate_hz: float = 10.0,
    up_axis: str = "z_up",
    gravity: float = STANDARD_GRAVITY,
    temp_noise: float = 0.01,
) -> Recording:
    """A static soak, one attitude, chamber ramped t_low -> t_high -> t_low at a constant rate.

    Every sample gets the error model of its temperature and direction (heating
    on the way up, cooling on the way down) plus the unit's white noise; the
    temperature channel has `temp_noise` deg C of noise.
    """
    half_s = (t_high - t_low) / rate_c_per_min * 60.0
    t = np.arange(int(2 * half_s * rate_hz)) / rate_hz
    up = t < half_s
    temp = np.where(
        up, t_low + (t_high - t_low) * t / half_s, t_high - (t_high - t_low) * (t - half_s) / half_s
    )
    f = axis_vector(up_axis, gravity)
    n = t.shape[0]
    acc = np.empty((n, 3))
    gyr = np.empty((n, 3))
    for direction, sel in ((HEATING, up), (COOLING, ~up)):
        T = temp[sel]
        for sensor, out, noise in (
            ("acc", acc, truth.base.acc_noise),
            ("gyr", gyr, truth.base.gyr_noise),
        ):
            bias = np.stack(
                [truth.value(params.bias(sensor, a), T, direction) for a in params.AXES], 1
            )
            if sensor == "acc":
                M = np.stack(  # noqa: N806
                    [
                        np.stack([truth.value(c, T, direction) for c in row], -1)
                        for row in params.matrix_names("acc")
                    ],
                    -2,
                )
                clean = (np.eye(3) + M) @ f + bias
            else:
                G = np.stack(  # noqa: N806
                    [
                        np.stack([truth.value(c, T, direction) for c in row], -1)
                        for row in params.gsens_names()
                    ],
                    -2,
                )
                clean = G @ f + bias
            out[sel] = clean + rng.standard_normal((T.size, 3)) * noise
    temp_meas = temp + temp_noise * rng.standard_normal(n)
    return Recording(t, acc, gyr, temp_meas, label=up_axis, source="simulated soak sweep")


@dataclass
class HistoryEntry:
    """One re-calibration of a unit: when (days since the history's start) and its truth."""

    day: float
    errors: TrueErrors


def recalibration_history(
    base: TrueErrors,
    rng: np.random.Generator,
    *,
    n_runs: int = 12,
    interval_days: float = 30.0,
    jitter_days: float = 3.0,
    drift_per_day: Mapping[str, float] | None = None,
) -> list[HistoryEntry]:
    """Truth of a unit re-calibrated every ~interval_days, its parameters drifting linearly.

    drift_per_day : name -> SI change per day (e.g. {"gyr.bias.z": 1e-6}).
    """
    drift = dict(drift_per_day or {})
    start = base.parameters()
    days = np.arange(n_runs) * interval_days + rng.uniform(-jitter_days, jitter_days, n_runs)
    days[0] = 0.0
    return [
        HistoryEntry(
            float(d), set_parameters(base, {n: start[n] + rate * d for n, rate in drift.items()})
        )
        for d in np.sort(days)
    ]
