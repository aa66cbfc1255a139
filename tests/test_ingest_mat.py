"""MATLAB reader: v5 files from scipy.io.savemat, v7.3 files from hdf5storage (MATLAB's layout).

Expected values are the arrays written; float64 survives both formats bit for
bit, so samples compare exactly and unit conversions compare to the same
product computed here.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import hdf5storage
import numpy as np
import pytest
import scipy.io

from calib_core.units import DEG, STANDARD_GRAVITY
from pipelines.ingest.errors import IngestError
from pipelines.ingest.matlab import read_mat

T0 = 1_700_000_000.0  # Unix s


def simulated(n: int = 500, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "t": T0 + 0.01 * np.arange(n),
        "acc": rng.normal(0.0, 9.81, (n, 3)),
        "gyr": rng.normal(0.0, 0.5, (n, 3)),
        "temp": 25.0 + rng.normal(0.0, 0.1, n),
    }


def save(path: Path, data: dict, version: str) -> Path:
    if version == "5":
        scipy.io.savemat(path, data)
    else:
        hdf5storage.savemat(str(path), data, format="7.3", matlab_compatible=True)
    return path


VERSIONS = ["5", "7.3"]


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("seed", [0, 1])
def test_plain_arrays_round_trip(tmp_path, version, seed):
    truth = simulated(seed=seed)
    path = save(tmp_path / "run.mat", truth, version)
    rec = read_mat(path, variables={"t": "t", "acc": "acc", "gyr": "gyr", "temp": "temp"})
    for key in ("t", "acc", "gyr", "temp"):
        np.testing.assert_array_equal(getattr(rec, key), truth[key])
    assert rec.source == str(path)


@pytest.mark.parametrize("version", VERSIONS)
def test_struct_fields_transposed_triads_and_units(tmp_path, version):
    truth = simulated(n=300)
    acc_g = truth["acc"] / STANDARD_GRAVITY
    gyr_dps = truth["gyr"] / DEG
    imu = {"time": truth["t"], "acc": acc_g.T.copy(), "gyr": gyr_dps.T.copy()}  # (3, N)
    path = save(tmp_path / "run.mat", {"imu": imu}, version)
    rec = read_mat(
        path,
        variables={"t": "imu.time", "acc": "imu.acc", "gyr": "imu.gyr"},
        acc_unit="g",
        gyr_unit="deg/s",
    )
    np.testing.assert_array_equal(rec.acc, acc_g * STANDARD_GRAVITY)
    np.testing.assert_array_equal(rec.gyr, gyr_dps * DEG)
    np.testing.assert_array_equal(rec.t, truth["t"])
    assert rec.temp is None


@pytest.mark.parametrize("version", VERSIONS)
def test_per_axis_vectors_as_list_or_string(tmp_path, version):
    truth = simulated(n=200)
    data = {f"a{c}": truth["acc"][:, i] for i, c in enumerate("xyz")}
    data |= {f"w{c}": truth["gyr"][:, i] for i, c in enumerate("xyz")}
    data["data"] = {"t_ms": (truth["t"] - T0) * 1e3}
    path = save(tmp_path / "axes.mat", data, version)
    rec = read_mat(
        path,
        variables={"t": "data.t_ms", "acc": ["ax", "ay", "az"], "gyr": "wx, wy, wz"},
        time_unit="ms",
    )
    np.testing.assert_array_equal(rec.acc, truth["acc"])
    np.testing.assert_array_equal(rec.gyr, truth["gyr"])
    # ms -> s: one rounding of values <= 2000 ms and one of the product: < 1e-15 s here
    np.testing.assert_allclose(rec.t, truth["t"] - T0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("version", VERSIONS)
def test_datenum_time(tmp_path, version):
    truth = simulated(n=400)
    datenum = truth["t"] / 86400.0 + 719529.0  # MATLAB days since year 0
    path = save(
        tmp_path / "dn.mat", {"dn": datenum, "acc": truth["acc"], "gyr": truth["gyr"]}, version
    )
    rec = read_mat(path, variables={"t": "dn", "acc": "acc", "gyr": "gyr"}, time_unit="datenum")
    # A datenum near 7.4e5 days has a float64 spacing of 2**-33 days = 10.06 us; writing it
    # rounded by half of that, so the absolute time is good to ~5 us.
    spacing = 2.0**-33 * 86400.0
    np.testing.assert_allclose(rec.t, truth["t"], rtol=0, atol=spacing)
    # Spacing between samples is formed from exact datenum differences: each within 2 roundings.
    np.testing.assert_allclose(np.diff(rec.t), 0.01, rtol=0, atol=2 * spacing)


@pytest.mark.parametrize("version", VERSIONS)
def test_integer_nanoseconds_and_sample_rate(tmp_path, version):
    truth = simulated(n=100)
    ns = 1_700_000_000_000_000_000 + 2_500_000 * np.arange(100, dtype=np.int64)
    path = save(tmp_path / "ns.mat", {"t": ns, "acc": truth["acc"], "gyr": truth["gyr"]}, version)
    rec = read_mat(path, variables={"t": "t", "acc": "acc", "gyr": "gyr"}, time_unit="ns")
    # integer offsets are exact; float64 at 1.7e9 s resolves 2**-22 s
    np.testing.assert_allclose(rec.t, ns / 1e9, rtol=0, atol=2.0**-22)
    np.testing.assert_allclose(np.diff(rec.t), 2.5e-3, rtol=0, atol=2.0**-22)
    rec = read_mat(path, variables={"acc": "acc", "gyr": "gyr"}, sample_rate_hz=400.0)
    np.testing.assert_array_equal(rec.t, np.arange(100) / 400.0)


# --- bad input ------------------------------------------------------------------------


def _raises(path: Path, match: str, **kwargs) -> IngestError:
    kwargs.setdefault("variables", {"t": "t", "acc": "acc", "gyr": "gyr"})
    with pytest.raises(IngestError, match=match) as info:
        read_mat(path, **kwargs)
    assert str(path) in str(info.value)
    return info.value


@pytest.mark.parametrize("version", VERSIONS)
def test_missing_variable_lists_what_the_file_holds(tmp_path, version):
    truth = simulated(n=50)
    path = save(
        tmp_path / "run.mat",
        {"imu": {"acc": truth["acc"]}, "gyro": truth["gyr"], "t": truth["t"]},
        version,
    )
    err = _raises(
        path, r"variable 'gyr' not found", variables={"t": "t", "acc": "imu.acc", "gyr": "gyr"}
    )
    assert "gyro" in str(err) and "imu" in str(err) and err.field == "gyr"
    err = _raises(
        path,
        r"variable 'imu.gyr' not found \(no 'gyr' in imu\)",
        variables={"t": "t", "acc": "imu.acc", "gyr": "imu.gyr"},
    )
    _raises(path, "is a struct", variables={"t": "t", "acc": "imu", "gyr": "gyro"})


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_name_variable_and_sample(tmp_path, version, bad):
    truth = simulated(n=80)
    truth["gyr"][57, 2] = bad
    path = save(tmp_path / "run.mat", truth, version)
    err = _raises(path, r"non-finite value .* at sample index 57")
    assert err.field == "gyr"


@pytest.mark.parametrize("version", VERSIONS)
def test_non_increasing_and_duplicated_time(tmp_path, version):
    truth = simulated(n=80)
    truth["t"][30] = truth["t"][29]
    path = save(tmp_path / "dup.mat", truth, version)
    _raises(path, r"not strictly increasing at sample index 30")
    truth = simulated(n=80)
    truth["t"][60] = truth["t"][50]
    path = save(tmp_path / "back.mat", truth, version)
    _raises(path, r"not strictly increasing at sample index 60")


@pytest.mark.parametrize("version", VERSIONS)
def test_mismatched_lengths(tmp_path, version):
    truth = simulated(n=80)
    truth["gyr"] = truth["gyr"][:79]
    path = save(tmp_path / "run.mat", truth, version)
    err = _raises(path, r"has 79 samples but 'acc' has 80")
    assert err.field == "gyr"
    truth = simulated(n=80)
    truth["ax"], truth["ay"], truth["az"] = truth["acc"][:, 0], truth["acc"][:-1, 1], truth["t"]
    path = save(tmp_path / "axes.mat", truth, version)
    _raises(path, r"has 79 samples", variables={"acc": "ax,ay,az", "gyr": "gyr", "t": "t"})


@pytest.mark.parametrize("version", VERSIONS)
def test_wrong_type_or_shape(tmp_path, version):
    truth = simulated(n=40)
    truth["name"] = "unit 17"
    truth["acc4"] = np.zeros((40, 4))
    path = save(tmp_path / "run.mat", truth, version)
    _raises(
        path,
        "expected (a numeric array|numbers)",
        variables={"t": "t", "acc": "name", "gyr": "gyr"},
    )
    variables = {"t": "t", "acc": "acc4", "gyr": "gyr"}
    _raises(path, r"expected \(N, 3\) or \(3, N\)", variables=variables)


@pytest.mark.parametrize("version", VERSIONS)
def test_truncated_file(tmp_path, version):
    path = save(tmp_path / "run.mat", simulated(n=300), version)
    data = path.read_bytes()
    for cut in (100, 600, len(data) // 2, len(data) - 10):
        bad = tmp_path / f"cut{cut}.mat"
        bad.write_bytes(data[:cut])
        _raises(bad, "truncated|cannot|not a MATLAB|not found|unknown file format")


def test_not_a_mat_file(tmp_path):
    path = tmp_path / "run.mat"
    path.write_text("t,ax,ay,az\n0,1,2,3\n")
    _raises(path, "not a MATLAB .mat file: content looks like text")
    path.write_bytes(b"PK\x03\x04" + bytes(200))
    _raises(path, "unknown file format.*50 4b 03 04")


def test_bad_arguments(tmp_path):
    path = save(tmp_path / "run.mat", simulated(n=20), "5")
    _raises(path, "unknown role", variables={"acc": "acc", "gyr": "gyr", "mag": "m"})
    _raises(path, "no MATLAB variable given for 'gyr'", variables={"acc": "acc"})
    _raises(path, "expected one name or three names", variables={"acc": "a,b", "gyr": "gyr"})
    _raises(path, "unknown acceleration unit", acc_unit="furlong/s^2")
    _raises(path, "sample rate", variables={"acc": "acc", "gyr": "gyr"})


def test_plain_hdf5_without_matlab_attributes_is_not_transposed(tmp_path):
    """An HDF5 file written by h5py (no MATLAB_class): shapes are taken as they are."""
    truth = simulated(n=50)
    path = tmp_path / "plain.h5"
    with h5py.File(path, "w") as f:
        for key in ("t", "acc", "gyr"):
            f[key] = truth[key]
    rec = read_mat(path, variables={"t": "t", "acc": "acc", "gyr": "gyr"})
    np.testing.assert_array_equal(rec.acc, truth["acc"])


@pytest.mark.parametrize("version", VERSIONS)
def test_a_value_no_imu_reads_is_refused_at_read(tmp_path, version):
    """A finite but impossible reading (1e30 m/s^2, a damaged value) is refused when the run
    is read, naming the file and the sample, before any preprocessing or solve."""
    from test_ingest_formats_e2e import manifest

    from pipelines.ingest import discover_runs, load_run

    n = 200
    rng = np.random.default_rng(7)
    acc = rng.normal(0, 0.01, (n, 3)) + (0, 0, 9.81)
    acc[57, 1] = 1e30
    folder = tmp_path / "run"
    folder.mkdir()
    data = {"t": np.arange(n) / 100.0, "acc": acc, "gyr": rng.normal(0, 0.01, (n, 3))}
    path = save(folder / "a.mat", data, version)
    fmt = {"kind": "mat", "variables": {"t": "t", "acc": "acc", "gyr": "gyr"}}
    (folder / "run.toml").write_text(manifest("SIM-MAT", fmt, [{"label": "z_up", "file": "a.mat"}]))
    with pytest.raises(IngestError, match=r"sample 57 .*beyond what any IMU") as err:
        load_run(discover_runs([folder])[0])
    assert err.value.file == str(path)
