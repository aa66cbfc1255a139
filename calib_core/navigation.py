"""Navigation performance, the science: a unit's calibrated residual errors propagated through
the strapdown inertial error equations over a mission profile (`calib_core.mission`), as a
linear covariance analysis with an error budget (docs/navigation.md).

Error state (psi-angle formulation; Titterton & Weston 2004, sec. 12.3.3 and 12.5;
Benson 1975), navigation frame n = local North-East-Down:

    psi' = -omega_in x psi - C_b^n d_omega                       attitude (rad)
    dv'  =  f^n x psi - (2 omega_ie + omega_en) x dv + dg + C_b^n d_f    velocity (m/s)
    dr'  =  dv                                                    position (m)
    dg   =  (-g/R dr_N, -g/R dr_E, +2 g/R dr_D)                   (T&W eq. 12.29)

The gravity-gradient term dg gives the Schuler oscillation of the horizontal channels
(period 2 pi sqrt(R/g) = 84.4 min) and the unstable vertical channel; omega_ie is the Earth
rate and omega_en the transport rate (Groves 2013, eqs. 5.44 and 5.41). The attitude error
reported is phi = psi + d_theta, d_theta = (dr_E/R, -dr_N/R, -dr_E tan(L)/R) the angle of
the position error (T&W eq. 12.31). d_omega and d_f are the sensor errors in the body frame:

    d_omega = b_g + dM_g omega_ib^b + dG f^b + n_g,    d_f = b_a + dM_a f^b + n_a

Error sources (`ErrorSource`): each calibrated parameter's standard uncertainty u
(= U / k) as a random constant (the
family's covariance block when known), the thermal model's residual over the profile's
temperatures and the drift expected at the end of the recalibration interval as random
constants; angle / velocity random walk (ARW, VRW) as white noise of PSD N^2; rate random
walk K as a random walk of PSD K^2; bias instability B as a first-order Gauss-Markov
process of steady-state std 1.0744 B and correlation time tau_min / 1.89, whose Allan
deviation peaks at the flicker floor 0.6643 B at the flicker's minimum tau_min (IEEE Std
952-1997 Annex C; the Gauss-Markov peak 0.6183 sigma at 1.89 tau_c). The state
(`StateLayout`): the 9 navigation errors, one state per parameter with a constant error
(its u, thermal residual and drift share it), the Markov and random-walk states.

Propagation (Groves 2013, sec. 3.2.2 and 3.2.3): Phi_k = expm(F_k dt) with F at the
step's midpoint (`expm_batch`), Q_k = (Phi Q_c Phi^T + Q_c) dt / 2. Fixes while aided
update every state with the Kalman gain of the total covariance (an optimal filter over
the whole model: a best case; a filter with fewer states does worse). With the gains so
fixed the errors are linear in the sources, so each source is propagated alone with the
same Phi and gains (constants as the state's sensitivity to their values, every other
source as its own covariance, P_j+ = (I - K H) P_j (I - K H)^T, the fixes' own noise
K R K^T a source of its own) and the shares of each output's variance add up to the total
exactly.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from calib_core.earth import EARTH_RATE, gravity_wgs84, radii_of_curvature
from calib_core.mission import MissionProfile

AXES = "xyz"
NAV = 9  # psi (3), dv (3), dr (3)
OUTPUTS = (
    "roll", "pitch", "heading",
    "velocity_north", "velocity_east", "velocity_down",
    "position_north", "position_east", "position_down",
)  # fmt: skip
GM_SIGMA_PER_B = 0.6643 / 0.6183  # Gauss-Markov std whose Allan peak is the flicker floor
GM_TAU_PER_MIN = 1.0 / 1.89  # its correlation time per Allan-minimum cluster time
FAMILIES = ("bias", "scale", "misalign", "gsens")


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices [v x] of (..., 3) vectors."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2
    )


@dataclass(frozen=True)
class ErrorSource:
    """One group of error states, or of white noise.

    Attributes
    ----------
    name : as shown in the budget ("gyr.bias", "acc.vrw", "thermal acc.bias", ...).
    sensor : "gyr" or "acc" (the sensor error it adds to); "nav" for initial errors.
    kind : "constant", "white", "random_walk", "markov" or "initial".
    inputs : per state, (output axis 0..2, "1" | "w" | "f", input axis 0..2): the state
        multiplies 1, omega_ib^b[input] or f^b[input] in the sensor's output axis.
    names : a constant's parameter names, one per state: constants of one parameter (its
        calibration's u, thermal residual, drift) share that parameter's state.
    cov0 : (n, n) initial covariance of the states (constants, Markov steady state);
        for "initial" the (9, 9) of the navigation errors.
    psd : (n,) white-noise PSD driving each state (random walk K^2, Markov 2 sigma^2 / tau)
        or, for "white", of each axis' sensor noise (N^2).
    tau : (n,) Markov correlation times, s (inf otherwise).
    """

    name: str
    sensor: str
    kind: str
    inputs: tuple[tuple[int, str, int], ...] = ()
    cov0: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    psd: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tau: np.ndarray = field(default_factory=lambda: np.zeros(0))
    names: tuple[str, ...] = ()

    @property
    def n_states(self) -> int:
        """States of its own (Markov, random walk); constants use their parameters' states."""
        return len(self.inputs) if self.kind in ("markov", "random_walk") else 0


@dataclass(frozen=True)
class ErrorModel:
    """A unit's residual error sources and what could not be modelled (notes)."""

    sources: tuple[ErrorSource, ...]
    notes: tuple[str, ...] = ()


def parameter_input(name: str) -> tuple[str, tuple[int, str, int]]:
    """(sensor, input) of a canonical bias / scale / misalign / gsens parameter name."""
    sensor, family, axes = name.split(".")
    out = AXES.index(axes[0])
    if family == "bias":
        return sensor, (out, "1", 0)
    if family == "scale":
        return sensor, (out, "w" if sensor == "gyr" else "f", out)
    if family == "misalign":
        return sensor, (out, "w" if sensor == "gyr" else "f", AXES.index(axes[1]))
    if family == "gsens":
        return sensor, (out, "f", AXES.index(axes[1]))
    raise ValueError(f"{name}: no navigation error input for family {family!r}")


def _constants(
    prefix: str, stds: Mapping[str, float], covariance: Mapping[tuple[str, str], float]
) -> list[ErrorSource]:
    """One constant source per parameter family (its covariance block when given)."""
    out = []
    groups: dict[str, list[str]] = {}
    for name, u in stds.items():
        if u is not None and np.isfinite(u) and u > 0:
            groups.setdefault(name.rsplit(".", 1)[0], []).append(name)
    for family, names in sorted(groups.items()):
        names.sort()
        cov = np.diag([float(stds[n]) ** 2 for n in names])
        for i, a in enumerate(names):
            for j, b in enumerate(names):
                if i != j and (a, b) in covariance:
                    cov[i, j] = covariance[a, b]
        sensor = family.split(".")[0]
        inputs = tuple(parameter_input(n)[1] for n in names)
        n = len(names)
        out.append(
            ErrorSource(
                f"{prefix}{family}",
                sensor,
                "constant",
                inputs,
                cov,
                np.zeros(n),
                np.full(n, np.inf),
                tuple(names),
            )
        )
    return out


def _noise_sources(noise: Mapping[str, Sequence[Mapping]]) -> tuple[list[ErrorSource], list[str]]:
    """ARW / VRW (white), bias instability (Gauss-Markov), rate random walk of each sensor."""
    out, notes = [], []
    bias_inputs = tuple((i, "1", 0) for i in range(3))
    for sensor, white in (("gyr", "arw"), ("acc", "vrw")):
        terms = noise.get(sensor)
        if not terms:
            notes.append(f"{sensor}: no noise terms in the calibration (no Allan record)")
            continue
        n = np.array([float(d["arw"]) for d in terms])
        b = np.array([float(d.get("bias_instability") or 0.0) for d in terms])
        k = np.array([float(d.get("rrw") or 0.0) for d in terms])
        tmin = np.array([float(d.get("bias_instability_tau") or np.nan) for d in terms])
        if np.any(n > 0):
            out.append(ErrorSource(f"{sensor}.{white}", sensor, "white", bias_inputs, psd=n**2))
        if np.any(b > 0):
            if not np.isfinite(tmin).all():
                notes.append(f"{sensor}: bias instability without its cluster time: left out")
            else:
                sigma, tau = GM_SIGMA_PER_B * b, GM_TAU_PER_MIN * tmin
                out.append(
                    ErrorSource(
                        f"{sensor}.bias_instability",
                        sensor,
                        "markov",
                        bias_inputs,
                        np.diag(sigma**2),
                        2 * sigma**2 / tau,
                        tau,
                    )
                )
        if np.any(k > 0):
            out.append(
                ErrorSource(
                    f"{sensor}.rrw", sensor, "random_walk", bias_inputs,
                    np.zeros((3, 3)), k**2, np.full(3, np.inf),
                )
            )  # fmt: skip
    return out, notes


def error_model(
    uncertainties: Mapping[str, float],
    noise: Mapping[str, Sequence[Mapping]] | None = None,
    *,
    covariance: Mapping[tuple[str, str], float] | None = None,
    thermal: Mapping[str, float] | None = None,
    drift: Mapping[str, float] | None = None,
) -> ErrorModel:
    """The residual error sources of a calibrated unit.

    Parameters
    ----------
    uncertainties : canonical parameter name -> standard uncertainty u (SI). Names outside
        the bias / scale / misalign / gsens families are left out with a note.
    noise : sensor ("gyr", "acc") -> three dicts with "arw" (N, unit/sqrt(Hz)),
        "bias_instability" (B, unit), "rrw" (K, unit/sqrt(s)), "bias_instability_tau" (s):
        the static-bias solver's ``noise_parameters``.
    covariance : (name, name) -> covariance of two parameters of one family.
    thermal : name -> std of the thermal model's residual over the profile's temperatures.
    drift : name -> the change expected by the end of the recalibration interval (1 sigma).
    """
    notes: list[str] = []

    def usable(stds: Mapping[str, float] | None, what: str) -> dict[str, float]:
        keep = {}
        for name, u in (stds or {}).items():
            sensor, family = name.split(".")[:2]
            if family in FAMILIES:
                keep[name] = float(u) if u is not None else None
            elif family == "noise":
                continue  # a sample std, not a density: the Allan terms (or their note)
            else:
                notes.append(f"{what}{name}: not an error of the navigation model, left out")
        return keep

    cov = dict(covariance or {})
    sources = _constants("", usable(uncertainties, ""), cov)
    sources += _constants("thermal ", usable(thermal, "thermal "), {})
    sources += _constants("drift ", usable(drift, "drift "), {})
    extra, more = _noise_sources(noise or {})
    return ErrorModel(tuple(sources + extra), tuple(notes + more))


@dataclass(frozen=True)
class StateLayout:
    """The full state: navigation errors (9), one state per parameter with a constant
    error, then the Markov and random-walk sources' own states.

    Attributes
    ----------
    sources : every source, the profile's "initial errors" and "fix noise" last.
    params : the parameters' names, states NAV .. NAV + len(params).
    offsets : per source, the first of its own states (Markov, random walk), else -1.
    n : the state's size.
    """

    sources: tuple[ErrorSource, ...]
    params: tuple[str, ...]
    offsets: tuple[int, ...]
    n: int

    def columns(self, j: int) -> list[int]:
        """The states source j starts in (its initial covariance's rows)."""
        s = self.sources[j]
        if s.kind == "initial":
            return list(range(NAV))
        if s.kind == "constant":
            return [NAV + self.params.index(n) for n in s.names]
        return list(range(self.offsets[j], self.offsets[j] + s.n_states))

    def is_constant(self, j: int) -> bool:
        """Constants and initial errors: propagated as sensitivities, no process noise."""
        return self.sources[j].kind in ("constant", "initial") and self.sources[j].name != FIX


FIX = "fix noise"


def state_layout(profile: MissionProfile, model: ErrorModel) -> StateLayout:
    """The model's sources with the profile's initial errors and the fixes' noise, and
    where each sits in the state vector."""
    init = ErrorSource("initial errors", "nav", "initial", cov0=np.diag(profile.initial_std**2))
    fix = ErrorSource(FIX, "nav", "initial", cov0=np.zeros((NAV, NAV)))
    sources = (*model.sources, init, fix)
    params = tuple(sorted({n for s in sources if s.kind == "constant" for n in s.names}))
    offsets, n = [], NAV + len(params)
    for s in sources:
        offsets.append(n if s.n_states else -1)
        n += s.n_states
    return StateLayout(sources, params, tuple(offsets), n)


def _earth(profile: MissionProfile) -> tuple[float, float, np.ndarray]:
    """(R, g, omega_ie^n) at the start point."""
    rn, re = radii_of_curvature(profile.latitude)
    lat = profile.latitude
    g = gravity_wgs84(math.degrees(lat), profile.height)
    w_ie = EARTH_RATE * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    return math.sqrt(rn * re) + profile.height, g, w_ie


def _dynamics(
    profile: MissionProfile, layout: StateLayout, times: np.ndarray
) -> dict[str, np.ndarray]:
    """F (T, n, n) at `times` and what the white noises need: C_b^n (T, 3, 3)."""
    R, g, w_ie = _earth(profile)
    kin = profile.trajectory.kinematics(times)
    C, v = kin["dcm"], kin["velocity"]
    tan_l = math.tan(profile.latitude)
    w_en = np.stack([v[:, 1] / R, -v[:, 0] / R, -v[:, 1] * tan_l / R], axis=-1)
    w_in = w_ie + w_en
    g_n = np.array([0.0, 0.0, g])
    f_n = kin["acceleration"] - g_n + np.cross(2 * w_ie + w_en, v)
    f_b = np.einsum("tji,tj->ti", C, f_n)
    w_b = kin["omega_nb"] + np.einsum("tji,tj->ti", C, w_in)
    T = times.size
    F = np.zeros((T, layout.n, layout.n))
    F[:, 0:3, 0:3] = -skew(w_in)
    F[:, 3:6, 0:3] = skew(f_n)
    F[:, 3:6, 3:6] = -skew(2 * w_ie + w_en)
    F[:, 3:6, 6:9] = np.diag([-g / R, -g / R, 2 * g / R])
    F[:, 6:9, 3:6] = np.eye(3)
    blocks = [(NAV + i, *parameter_input(name)) for i, name in enumerate(layout.params)]
    for s, off in zip(layout.sources, layout.offsets, strict=True):
        blocks += [(off + j, s.sensor, inp) for j, inp in enumerate(s.inputs) if s.n_states]
        if s.kind == "markov":
            F[:, off : off + s.n_states, off : off + s.n_states] = -np.diag(1.0 / s.tau)
    for col, sensor, (out, kind, inp) in blocks:
        b = np.ones(T) if kind == "1" else (w_b if kind == "w" else f_b)[:, inp]
        if sensor == "gyr":  # psi' = ... - C_b^n d_omega
            F[:, 0:3, col] = -C[:, :, out] * b[:, None]
        else:  # dv' = ... + C_b^n d_f
            F[:, 3:6, col] = C[:, :, out] * b[:, None]
    return {"F": F, "C": C}


def _noise_density(s: ErrorSource, off: int, n: int, C: np.ndarray) -> np.ndarray:
    """Continuous-time Q_c (T, n, n) of one source (zero for constants)."""
    Q = np.zeros((C.shape[0], n, n))
    if s.kind == "white":
        rows = slice(0, 3) if s.sensor == "gyr" else slice(3, 6)
        Q[:, rows, rows] = C @ np.diag(s.psd) @ np.swapaxes(C, -1, -2)
    elif s.kind in ("markov", "random_walk"):
        Q[:, off : off + s.n_states, off : off + s.n_states] = np.diag(s.psd)
    return Q


def output_matrix(profile: MissionProfile, n: int) -> np.ndarray:
    """(9, n): the state -> roll, pitch, heading error phi = psi + d_theta, velocity and
    position errors (T&W eq. 12.31)."""
    R, _, _ = _earth(profile)
    M = np.zeros((NAV, n))
    M[:, :NAV] = np.eye(NAV)
    M[0, 7] += 1.0 / R
    M[1, 6] += -1.0 / R
    M[2, 7] += -math.tan(profile.latitude) / R
    return M


@dataclass(frozen=True)
class Propagation:
    """The covariance of the navigation errors over a profile, by source.

    Attributes
    ----------
    t : (T,) s, the recorded times.
    sources : (S,) names; the last two are "initial errors" and "fix noise".
    cov : (S, T, 9, 9) each source's covariance of the outputs (OUTPUTS: roll, pitch,
        heading rad; velocity N E D m/s; position N E D m).
    gains : the Kalman gains used, {step index: (n, m)} (the fixes: `fix_steps`).
    step : the propagation step, s; n_states : the full state's size.
    """

    t: np.ndarray
    sources: tuple[str, ...]
    cov: np.ndarray
    gains: dict[int, np.ndarray]
    step: float
    n_states: int

    def total(self) -> np.ndarray:
        """(T, 9, 9) the covariance of all sources together."""
        return self.cov.sum(axis=0)

    def sigma(self) -> np.ndarray:
        """(T, 9) 1-sigma of each output."""
        return np.sqrt(np.maximum(np.diagonal(self.total(), axis1=-2, axis2=-1), 0.0))


def initial_covariance(layout: StateLayout, j: int) -> np.ndarray:
    """(n, n) initial covariance of source j alone."""
    P = np.zeros((layout.n, layout.n))
    cols = layout.columns(j)
    P[np.ix_(cols, cols)] = layout.sources[j].cov0
    return P


def fix_steps(profile: MissionProfile) -> dict[int, tuple[list[int], np.ndarray]]:
    """Step index k (the state at k * step, k >= 1) -> (the observed navigation-state indices,
    their variances) of the fix applied there."""
    a = profile.aiding
    n_steps = int(round(profile.duration / profile.step))
    every = max(1, round(a.interval / profile.step))
    out = {}
    for k in range(every, n_steps + 1, every):
        obs = a.observed(k * profile.step)
        if obs[0]:
            out[k] = obs
    return out


def linear_model(
    profile: MissionProfile, layout: StateLayout, times: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The continuous-time error model at `times` (s): F (T, n, n) and the noise density
    Q_c (S', T, n, n) of each source that is not a constant (`StateLayout.is_constant`), in
    their order (what the covariance and the Monte Carlo check share)."""
    dyn = _dynamics(profile, layout, np.asarray(times, dtype=float))
    Qc = np.stack(
        [
            _noise_density(s, off, layout.n, dyn["C"])
            for j, (s, off) in enumerate(zip(layout.sources, layout.offsets, strict=True))
            if not layout.is_constant(j)
        ]
    )
    return dyn["F"], Qc


def transition(F: np.ndarray, dt: float) -> np.ndarray:
    """Phi = expm(F dt) of each (T, n, n) F, computed once per distinct F (a profile's
    straight stretches and rests repeat a few F step after step)."""
    first: dict[bytes, int] = {}
    which = np.array([first.setdefault(f.tobytes(), len(first)) for f in F])
    unique = np.array([F[i] for i in np.unique(which, return_index=True)[1]])
    return expm_batch(unique * dt)[which]


TAYLOR_ORDER = 12


def expm_batch(A: np.ndarray) -> np.ndarray:
    """expm of each (T, n, n) matrix: scaling and squaring of the Taylor series (Moler & Van
    Loan 2003, method 3): A / 2^s with a 1-norm <= 1/2, the series to TAYLOR_ORDER (its
    truncation below 0.5^13 / 13! = 2e-14 of the norm), squared s times. One numpy
    product per term for the whole batch."""
    norm = np.abs(A).sum(axis=-2).max() if A.size else 0.0
    s = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    A = A / 2.0**s
    eye = np.eye(A.shape[-1])
    E = eye + A / TAYLOR_ORDER
    for k in range(TAYLOR_ORDER - 1, 0, -1):  # Horner: I + A/1 (I + A/2 (I + ...))
        E = eye + (A @ E) / k
    for _ in range(s):
        E = E @ E
    return E


class _Budget:
    """The error state's covariance kept by source: constants (and initial errors) as
    sensitivities X (n, m) of the state to their m values of covariance C (the error is
    X c), each other source as its own covariance P_j. Both move linearly, so the total,
    X C X^T + sum P_j, and each source's part are exact."""

    def __init__(self, layout: StateLayout) -> None:
        self.layout = layout
        const = [j for j in range(len(layout.sources)) if layout.is_constant(j)]
        self.noisy = [j for j in range(len(layout.sources)) if not layout.is_constant(j)]
        cols = [layout.columns(j) for j in const]
        sizes = [len(c) for c in cols]
        self.X = np.eye(layout.n)[:, [c for cs in cols for c in cs]]
        self.C = np.zeros((sum(sizes), sum(sizes)))
        self.parts = []  # (source index, slice of X's columns)
        at = 0
        for j, m in zip(const, sizes, strict=True):
            self.C[at : at + m, at : at + m] = layout.sources[j].cov0
            self.parts.append((j, slice(at, at + m)))
            at += m
        self.P = np.stack([initial_covariance(layout, j) for j in self.noisy])

    def step(self, Phi: np.ndarray, Qd: np.ndarray) -> None:
        self.X = Phi @ self.X
        self.P = Phi @ self.P @ Phi.T + Qd

    def total(self) -> np.ndarray:
        return self.X @ self.C @ self.X.T + self.P.sum(axis=0)

    def update(self, idx: list[int], var: np.ndarray) -> np.ndarray:
        """A fix of the states `idx` with noise variances `var`: the Kalman gain (n, m)."""
        n = self.layout.n
        H, Rm = np.eye(n)[idx], np.diag(var)
        Pt = self.total()
        K = np.linalg.solve(H @ Pt @ H.T + Rm, H @ Pt).T
        A = np.eye(n) - K @ H
        self.X = A @ self.X
        self.P = A @ self.P @ A.T
        self.P[self.noisy.index(len(self.layout.sources) - 1)] += K @ Rm @ K.T
        return K

    def outputs(self, M: np.ndarray) -> np.ndarray:
        """(S, 9, 9) each source's covariance of the outputs M x, in the sources' order."""
        out = np.zeros((len(self.layout.sources), M.shape[0], M.shape[0]))
        for j, cols in self.parts:
            Y = M @ self.X[:, cols]
            out[j] = Y @ self.C[cols, cols] @ Y.T
        out[self.noisy] = M @ self.P @ M.T
        return out


def propagate(profile: MissionProfile, model: ErrorModel, *, records: int = 600) -> Propagation:
    """The covariance of the navigation errors over `profile`, each source alone.

    Parameters
    ----------
    profile : the mission.
    model : the unit's error sources (`error_model`).
    records : about this many recorded times (the end always recorded).

    Returns
    -------
    Propagation.
    """
    layout = state_layout(profile, model)
    budget = _Budget(layout)
    dt = profile.step
    n_steps = int(round(profile.duration / dt))
    fixes = fix_steps(profile)
    M = output_matrix(profile, layout.n)
    stride = max(1, n_steps // records)
    keep = set(range(0, n_steps, stride))
    t_out, cov_out, gains = [], [], {}
    chunk = 100
    for k0 in range(0, n_steps, chunk):
        k1 = min(n_steps, k0 + chunk)
        F, Qc = linear_model(profile, layout, (np.arange(k0, k1) + 0.5) * dt)
        Phi = transition(F, dt)
        for i, k in enumerate(range(k0, k1)):
            if k in keep:
                t_out.append(k * dt), cov_out.append(budget.outputs(M))
            Ph, Qi = Phi[i], Qc[:, i]
            budget.step(Ph, 0.5 * dt * (Ph @ Qi @ Ph.T + Qi))
            if k + 1 in fixes:
                gains[k + 1] = budget.update(*fixes[k + 1])
    t_out.append(n_steps * dt), cov_out.append(budget.outputs(M))
    cov = np.stack(cov_out, axis=1)
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    return Propagation(
        np.asarray(t_out), tuple(s.name for s in layout.sources), cov, gains, dt, layout.n
    )


_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(48)


def _inside(r: np.ndarray, l1: np.ndarray, l2: np.ndarray) -> np.ndarray:
    """P(|x| < r) of a 2-D normal with variances l1 >= l2 along its axes: the integral over
    x = r sin(theta) of the x density times P(|y| < r cos(theta)) (Gauss-Legendre)."""
    from scipy.special import erf

    th = 0.5 * np.pi * _NODES
    x = r[:, None] * np.sin(th)
    pdf = np.exp(-0.5 * x**2 / l1[:, None]) / np.sqrt(2 * np.pi * l1[:, None])
    py = erf(r[:, None] * np.cos(th) / np.sqrt(2 * l2[:, None]))
    return 0.5 * np.pi * (pdf * py * r[:, None] * np.cos(th)) @ _WEIGHTS


def radius_95(cov2: np.ndarray) -> np.ndarray:
    """Radius holding 95 % of a 2-D normal error, (T,) from (T, 2, 2) covariances, by
    bisection (1.96 sigma for a line, 2.448 sigma for a circle)."""
    lam = np.linalg.eigvalsh(cov2)
    l1 = np.maximum(lam[:, 1], 1e-300)
    l2 = np.maximum(lam[:, 0], 1e-12 * l1)
    lo, hi = 1.959 * np.sqrt(l1), 2.45 * np.sqrt(l1 + l2)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = _inside(mid, l1, l2) < 0.95
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


Z95 = 1.959963984540054  # two-sided 95 % of a normal

# output groups of the budget: name -> indices of OUTPUTS whose variances add
GROUPS = {
    "roll": [0],
    "pitch": [1],
    "heading": [2],
    "horizontal_velocity": [3, 4],
    "vertical_velocity": [5],
    "horizontal_position": [6, 7],
    "vertical_position": [8],
}


def shares(prop: Propagation, index: int = -1) -> dict[str, dict[str, float]]:
    """Each source's share of each output group's variance at recorded time `index`:
    {group: {source: share}}, shares summing to 1 (sources with no share left out)."""
    out: dict[str, dict[str, float]] = {}
    var = np.diagonal(prop.cov[:, index], axis1=-2, axis2=-1)  # (S, 9)
    for group, idx in GROUPS.items():
        v = np.maximum(var[:, idx].sum(axis=1), 0.0)
        total = v.sum()
        out[group] = (
            {}
            if total <= 0
            else {
                s: float(x / total)
                for s, x in sorted(zip(prop.sources, v, strict=True), key=lambda p: -p[1])
                if x > 1e-6 * total
            }
        )
    return out


def performance(prop: Propagation, position_limit: float, free_from: float = 0.0) -> dict:
    """The figures of a propagation (SI: rad, m/s, m, s).

    Parameters
    ----------
    prop : the propagation.
    position_limit : m, a horizontal 95 % radius.
    free_from : s, when free inertial navigation starts (the outage): the time to the limit
        is counted from there (0 when the error is beyond the limit already).

    Returns
    -------
    {"t": (T,), "sigma": {output: (T,)}, "horizontal_velocity_95": (T,),
    "horizontal_position_95": (T,), "end": {output: {"sigma", "p95"}},
    "time_to_limit": s after `free_from`, or None when not reached by the end,
    "shares": ..., "dominant": {group: source}}.
    """
    tot = prop.total()
    sig = prop.sigma()
    hv = radius_95(tot[:, 3:5, 3:5])
    hp = radius_95(tot[:, 6:8, 6:8])
    t, r = prop.t, hp
    after = t >= free_from - 1e-9
    if after.any():  # the curve from the outage on, its start interpolated
        t = np.concatenate([[free_from], t[after]])
        r = np.concatenate([[np.interp(free_from, prop.t, hp)], hp[after]])
    over = np.nonzero(r > position_limit)[0]
    first = None
    if over.size:  # linear between the records around the crossing
        i = int(over[0])
        at = t[0] if i == 0 else np.interp(position_limit, r[i - 1 : i + 1], t[i - 1 : i + 1])
        first = float(at) - free_from
    end = {name: {"sigma": float(sig[-1, i]), "p95": Z95 * float(sig[-1, i])}
           for i, name in enumerate(OUTPUTS)}  # fmt: skip
    end["horizontal_velocity"] = {
        "sigma": float(np.hypot(sig[-1, 3], sig[-1, 4])), "p95": float(hv[-1])
    }  # fmt: skip
    end["horizontal_position"] = {
        "sigma": float(np.hypot(sig[-1, 6], sig[-1, 7])), "p95": float(hp[-1])
    }  # fmt: skip
    sh = shares(prop)
    return {
        "t": prop.t,
        "sigma": {name: sig[:, i] for i, name in enumerate(OUTPUTS)},
        "horizontal_velocity_95": hv,
        "horizontal_position_95": hp,
        "end": end,
        "position_limit": position_limit,
        "time_to_limit": first,
        "shares": sh,
        "dominant": {g: next(iter(s), None) for g, s in sh.items()},
    }
