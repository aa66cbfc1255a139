"""Every constant taken from a source, checked against a value from outside the code: the
source's own numbers written out here, a published table, or a second computation by
another route. A typo in a coefficient or a moved limit fails one of these.

Sources (docs/methods.md): [MPU] the MPU-6000 paper (tolerances 4.3, gravity 1.3), [RT]
the rate-table procedure (residual, verification, repeatability limits 3.6 - 3.8,
conditions 3.10), [CF] the centrifuge paper (F and t tests at alpha = 0.05).
"""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

from calib_core import conditions
from calib_core.distributions import f_ppf, t_ppf
from calib_core.earth import EARTH_RATE, FREE_AIR_GRADIENT, gravity_helmert, gravity_wgs84
from calib_core.preprocess.chain import DEFAULT_OUTLIERS
from calib_core.preprocess.outliers import hampel_mask, sigma_mask
from calib_core.solvers import static_bias
from calib_core.tolerances import (
    DEFAULT_REPEATABILITY,
    DEFAULT_RESIDUAL_LIMITS,
    DEFAULT_VERIFICATION_LIMITS,
)
from calib_core.units import STANDARD_GRAVITY
from pipelines.tolerances import load_profile

G0 = 9.80665  # m/s^2, standard gravity (CGPM 1901), written out
DPS = math.pi / 180.0  # rad/s per deg/s, written out


# --- the MPU-6000 profile: the paper's tolerance list, in its lab units ----------------------

# (pattern, low, high) in SI from the paper's list (docs/methods.md 4.3) and the residual
# limits (3.6); converted here, not by the loader.
PAPER_LIMITS = {
    "gyr.scale.x": 0.03,
    "gyr.misalign.yz": 0.02,
    "gyr.bias.y": 20 * DPS,
    "gyr.gsens.zx": 0.1 * DPS / G0,
    "acc.scale.z": 0.03,
    "acc.misalign.zx": 0.02,
    "acc.bias.x": 0.5,
    "acc.bias.y": 0.5,
    "acc.bias.z": 0.8,
}


@pytest.fixture
def shipped(monkeypatch, tmp_path):
    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path / "none"))  # shipped profiles only
    return load_profile("mpu6000")


def test_the_mpu6000_profile_holds_the_papers_tolerances(shipped):
    for name, bound in PAPER_LIMITS.items():
        lim = shipped.limit_for(name)
        assert (lim.low, lim.high) == (pytest.approx(-bound, rel=1e-12), pytest.approx(bound)), name
    noise = shipped.limit_for("gyr.noise.z")  # one-sided: noise 0.05 deg/s
    assert noise.low == -math.inf and noise.high == pytest.approx(0.05 * DPS, rel=1e-12)
    assert shipped.limit_for("acc.noise.x") is None  # the paper gives it no tolerance


def test_the_mpu6000_profile_holds_the_residual_and_verification_limits(shipped):
    """A residual-std limit moved from 2 mg to 20 mg fails here."""
    assert shipped.residual_limits == {
        "acc_std": pytest.approx(0.002 * G0, rel=1e-12),
        "acc_mean": pytest.approx(0.002 * G0, rel=1e-12),
        "gyr_std": pytest.approx(0.1 * DPS, rel=1e-12),
        "gyr_mean": pytest.approx(0.1 * DPS, rel=1e-12),
    }
    assert shipped.verification_limits == {
        "acc": pytest.approx(0.01 * G0, rel=1e-12),
        "gyr": pytest.approx(0.5 * DPS, rel=1e-12),
    }
    assert shipped.repeatability["cv_max"] == 0.01 and shipped.repeatability["min_runs"] == 3
    # the program's 50 Hz (15 s of data is 48-49 KB) and the consumer-grade warm-up
    assert shipped.conditions == {"sample_rate_hz": {"low": 45.0}, "warmup_min": {"low": 10.0}}
    assert shipped.protocol_names == "manual" and shipped.decision_rule.name == "simple"


def test_the_defaults_are_the_procedures_numbers():
    """docs/methods.md 3.6 - 3.8 and 3.10, written out in their units."""
    assert DEFAULT_RESIDUAL_LIMITS["acc_std"] == pytest.approx(0.002 * G0, rel=1e-12)
    assert DEFAULT_RESIDUAL_LIMITS["gyr_std"] == pytest.approx(0.1 * DPS, rel=1e-12)
    assert DEFAULT_VERIFICATION_LIMITS["acc"] == pytest.approx(0.01 * G0, rel=1e-12)
    assert DEFAULT_VERIFICATION_LIMITS["gyr"] == pytest.approx(0.5 * DPS, rel=1e-12)
    assert DEFAULT_REPEATABILITY["cv_max"] == 0.01 and DEFAULT_REPEATABILITY["min_runs"] == 3
    limits = {k: v[:2] for k, v in conditions.DEFAULT_CONDITIONS.items()}
    assert limits["ambient_temperature_c"] == (18.0, 22.0)  # 20 +- 2 deg C
    assert limits["temperature_drift_c_per_h"][1] == 0.5
    assert limits["humidity_pct"] == (40.0, 60.0)
    assert limits["sample_rate_hz"][0] == 100.0  # >= 100 Hz
    assert limits["settle_s"][0] == 30.0 and limits["settle_rate_s"][0] == 20.0
    assert limits["record_s"][0] == 10.0 and limits["static_record_min"][0] == 60.0


def test_the_3_sigma_defaults():
    """docs/methods.md 3.1 and 2.5: 3-sigma outlier rejection wherever it is the default."""
    assert DEFAULT_OUTLIERS["method"] == "sigma" and DEFAULT_OUTLIERS["n_sigma"] == 3.0
    # solve_static_bias takes its settings as keywords and leaves their defaults to
    # solve_static_bias_stream, the one solve (the in-memory record is its one-chunk case)
    for fn in (sigma_mask, hampel_mask, static_bias.solve_static_bias_stream):
        assert inspect.signature(fn).parameters["n_sigma"].default == 3.0, fn.__name__
    assert "n_sigma" in static_bias.StaticBiasSettings.__annotations__
    # behaviour: a sample at 3.5 sigma of a clean record is flagged, at 2.5 sigma not
    rng = np.random.default_rng(3)
    x = rng.standard_normal((20000, 1))
    x = (x - x.mean()) / x.std()
    x[100, 0], x[200, 0] = 3.5, 2.5
    flagged = sigma_mask(x)[:, 0]
    assert flagged[100] and not flagged[200]


# --- gravity ---------------------------------------------------------------------------------


def test_helmert_against_its_published_coefficients_and_wgs84():
    """Helmert's formula g = 9.80616 (1 - 0.0026373 cos 2phi + 0.0000059 cos^2 2phi)
    - 3.086e-6 h: its value at 45 deg is its leading coefficient; at the equator and the
    pole the hand-worked 9.80616 x 0.9973686 and 9.80616 x 1.0026432; and it stays within
    0.11 mGal x 1000 (1.1e-4 m/s^2, the difference of the Potsdam-era ellipsoid) of WGS84
    normal gravity, computed from WGS84's own defining constants by Somigliana's formula."""
    assert gravity_helmert(45.0) == pytest.approx(9.80616, abs=1e-12)
    assert gravity_helmert(0.0) == pytest.approx(9.7803561, abs=1e-7)
    assert gravity_helmert(90.0) == pytest.approx(9.8320796, abs=1e-7)
    assert gravity_helmert(-30.0) == gravity_helmert(30.0)
    for lat in np.arange(0.0, 90.5, 0.5):
        assert abs(gravity_helmert(float(lat)) - gravity_wgs84(float(lat))) < 1.1e-4, lat
    # the free-air term: 150 m lower the value by 150 x 3.086e-6
    assert gravity_helmert(55.75, 0.0) - gravity_helmert(55.75, 150.0) == pytest.approx(
        4.629e-4, abs=1e-12
    )


def test_the_free_air_gradient_is_twice_gravity_over_the_radius():
    """3.086e-6 s^-2 against the second-order normal-gravity gradient at 45 deg,
    (2 gamma / a)(1 + f + m - 2 f sin^2 phi), from WGS84's a, f and m (NIMA TR8350.2)."""
    a, f, m = 6378137.0, 1.0 / 298.257223563, 0.00344978650684
    gradient = 2.0 * 9.806199 / a * (1.0 + f + m - 2.0 * f * 0.5)
    assert pytest.approx(gradient, rel=2e-4) == FREE_AIR_GRADIENT
    assert FREE_AIR_GRADIENT == 3.086e-6


def test_wgs84_normal_gravity_at_the_equator_and_the_pole():
    """NIMA TR8350.2 (3rd ed.), Table 3.4: gamma_e = 9.7803253359, gamma_p = 9.8321849378."""
    assert gravity_wgs84(0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert gravity_wgs84(90.0) == pytest.approx(9.8321849378, abs=1e-9)


def test_earth_rate_and_standard_gravity():
    """Earth rate (the north-seeker note's input, the centrifuge's Omega_V): IERS
    Conventions (2010) Table 1.1, 7.292115e-5 rad/s, and by a second route one turn per
    sidereal day of 86164.0905 s (within the 1e-7 the nominal value is rounded to).
    Standard gravity 9.80665 m/s^2 (3rd CGPM, 1901)."""
    assert EARTH_RATE == 7.292115e-5
    assert pytest.approx(2.0 * math.pi / 86164.0905, rel=2e-7) == EARTH_RATE
    assert STANDARD_GRAVITY == G0


# --- the centrifuge paper's critical values --------------------------------------------------


def test_critical_values_against_the_printed_tables():
    """Upper 5 % points of F and t as printed in the standard tables (e.g. NIST/SEMATECH
    e-Handbook 1.3.6.7): F(10, 40) = 2.077, F(5, 60) = 2.368, F(10, 60) = 1.993,
    F(5, 40) = 2.449; t(0.975; 40) = 2.021, t(0.975; 60) = 2.000. The paper's 2.08 and 2.37
    are the first two (the nearest printed rows to its 49 and 54 degrees of freedom); the
    pipeline's exact F(10, 49) and F(5, 54) lie between the printed rows."""
    table = {(10, 40): 2.077, (5, 60): 2.368, (10, 60): 1.993, (5, 40): 2.449}
    for (dfn, dfd), value in table.items():
        assert f_ppf(0.95, dfn, dfd) == pytest.approx(value, abs=6e-4), (dfn, dfd)
    assert t_ppf(0.975, 40) == pytest.approx(2.021, abs=6e-4)
    assert t_ppf(0.975, 60) == pytest.approx(2.000, abs=6e-4)
    assert round(f_ppf(0.95, 10, 40), 2) == 2.08 and round(f_ppf(0.95, 5, 60), 2) == 2.37
    assert 1.993 < f_ppf(0.95, 10, 49) < 2.077 and 2.368 < f_ppf(0.95, 5, 54) < 2.449


def test_the_exact_critical_values_are_the_printed_table_interpolated():
    """docs/methods.md 2.8: the pipeline's F(10, 49) and F(5, 54) are the printed rows
    40 and 60 interpolated linearly in 1 / df2 (the rule printed with such tables), to the
    table's third decimal; the paper's 2.08 / 2.37 are the rows themselves, and neither a
    two-sided reading (the 0.975 points) nor another degrees-of-freedom count gives both."""
    rows = {10: (2.077, 1.993), 5: (2.449, 2.368)}  # F(k, 40), F(k, 60), printed

    def interpolated(k, df2):
        at40, at60 = rows[k]
        w = (1 / 40 - 1 / df2) / (1 / 40 - 1 / 60)
        return at40 + w * (at60 - at40)

    assert interpolated(10, 49) == pytest.approx(2.0307, abs=1e-4)  # worked by hand
    assert interpolated(5, 54) == pytest.approx(2.3860, abs=1e-4)
    # the pipeline's exact values against the interpolated table (0.0015: the rows'
    # rounding, 5e-4, plus the interpolation's curvature error)
    assert f_ppf(0.95, 10, 49) == pytest.approx(interpolated(10, 49), abs=1.5e-3)
    assert f_ppf(0.95, 5, 54) == pytest.approx(interpolated(5, 54), abs=1.5e-3)
    # the paper's values are the rows, not the interpolation (0.05 and 0.016 away)
    assert (round(rows[10][0], 2), round(rows[5][1], 2)) == (2.08, 2.37)
    assert abs(interpolated(10, 49) - 2.08) > 0.04 and abs(interpolated(5, 54) - 2.37) > 0.01
    # not a two-sided reading: the 0.975 points are far off
    assert f_ppf(0.975, 10, 49) > 2.3 and f_ppf(0.975, 5, 54) > 2.8
    # 2.08 needs df2 = 39 or 40 with k = 10, 2.37 df2 = 58 .. 61 with k = 5: with n = 60 no
    # one count (n - 1, n - k, n - k - 1, ...) gives both; the table's rows 40 and 60 do
    df2 = range(20, 130)
    assert [d for d in df2 if round(f_ppf(0.95, 10, d), 2) == 2.08] == [39, 40]
    assert [d for d in df2 if round(f_ppf(0.95, 5, d), 2) == 2.37] == [58, 59, 60, 61]
