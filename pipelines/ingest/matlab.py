"""MATLAB .mat reader (v5 via scipy, v7.3 via h5py) -> Recording.

Labs save their acquisition as plain arrays (``acc``, ``gyr``, ``t``) or as a
struct (``imu.acc``, ``imu.gyr``, ``imu.t``); which variable holds what, and in
which units, comes from the run manifest. The format (v5 or v7.3) is detected
from the file's content.

v7.3 files are HDF5. MATLAB stores arrays column-major, so an HDF5 dataset
written by MATLAB (or by hdf5storage) has the transposed shape: a MATLAB (N, 3)
array appears as (3, N). Datasets that carry a ``MATLAB_class`` attribute are
transposed back; a struct is a group whose ``MATLAB_class`` is ``struct``.

Time
----
``time_unit`` is one of s, ms, us, ns or ``datenum`` (MATLAB serial day
number, days since year 0). All are converted to seconds on the same epoch as
the input: s/ms/us/ns keep their own zero (often the Unix epoch or the start
of the log); datenum becomes Unix seconds, ``(dn - 719529) * 86400``.
Precision: the offsets from the first sample are formed in the input's own
representation before scaling (exact for integers, one rounding for floats),
so sample spacing keeps the input's resolution; only the first sample carries
the rounding of a large absolute value (float64 at 1.7e9 s: 0.24 us; a datenum
itself resolves only ~10 us).
"""

from __future__ import annotations

import contextlib
import os
import struct
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from calib_core.recording import Recording
from calib_core.units import acceleration_factor, angular_rate_factor, time_factor
from pipelines.ingest.detect import detect_format
from pipelines.ingest.errors import IngestError
from pipelines.ingest.isolated import run_isolated
from pipelines.ingest.time_order import check_time_increases

ROLES = ("t", "acc", "gyr", "temp")
TRIAD_ROLES = ("acc", "gyr")
DATENUM_UNIX_EPOCH = 719529.0  # MATLAB datenum of 1970-01-01 00:00:00
SECONDS_PER_DAY = 86400.0
_NUMERIC_KINDS = "biuf"  # bool, signed, unsigned, float


def read_mat(
    path: str | os.PathLike[str],
    *,
    variables: Mapping[str, str | Sequence[str]],
    time_unit: str = "s",
    acc_unit: str = "m/s^2",
    gyr_unit: str = "rad/s",
    sample_rate_hz: float | None = None,
) -> Recording:
    """Read IMU samples from a MATLAB v5 or v7.3 .mat file.

    Parameters
    ----------
    path : the .mat file (format detected from content).
    variables : MATLAB variable for each role: ``t``, ``acc``, ``gyr`` (required)
        and ``temp`` (optional). Struct fields are dotted (``"imu.acc"``). ``acc``
        and ``gyr`` are either one (N, 3) or (3, N) array, or three vectors given
        as a list of names or one comma-separated string (``"ax,ay,az"``).
    time_unit : s, ms, us, ns or datenum (see the module notes on epochs).
    acc_unit : unit of the accelerometer data (see calib_core.units), e.g. g.
    gyr_unit : unit of the gyro data, e.g. deg/s.
    sample_rate_hz : sample rate, Hz, used only when ``variables`` has no ``t``:
        then t = arange(N) / rate, s.

    Returns
    -------
    Recording with t (N,) s, acc (N, 3) m/s^2, gyr (N, 3) rad/s, temp (N,) deg C.

    Raises
    ------
    IngestError
        For a file that is not a .mat file or cannot be parsed, a missing
        variable (the message lists what the file holds), a variable of the
        wrong type or shape, mismatched lengths, NaN/inf or time that is not
        strictly increasing (with the 0-based sample index).
    """
    name = os.fspath(path)
    roles = _parse_variables(name, variables)
    acc_factor = _unit_factor(name, "format.acc_unit", acceleration_factor, acc_unit)
    gyr_factor = _unit_factor(name, "format.gyr_unit", angular_rate_factor, gyr_unit)
    if time_unit != "datenum":
        _unit_factor(name, "format.time_unit", time_factor, time_unit)

    fmt = detect_format(name)
    # A damaged file can crash scipy's or HDF5's native code: the file is first read in a
    # worker process (pipelines.ingest.isolated), which returns nothing but its errors, and
    # only a file that read there without crashing is read here.
    if fmt == "mat5":
        run_isolated(_probe, _load_mat5, name, roles, file=name, what="the MAT v5 reader (scipy)")
        raw = _load_mat5(name, roles)
    elif fmt == "mat73":
        run_isolated(_probe, _load_mat73, name, roles, file=name, what="the MAT v7.3 reader (HDF5)")
        raw = _load_mat73(name, roles)
    else:
        raise IngestError(f"not a MATLAB .mat file: content looks like {fmt}", file=name)

    t_raw = _vector(name, roles["t"][0], raw["t"]) if "t" in raw else None
    n = len(t_raw) if t_raw is not None else None
    acc = _triad(name, roles["acc"], raw["acc"], n)
    n = acc.shape[0]
    gyr = _triad(name, roles["gyr"], raw["gyr"], n)
    temp = None if "temp" not in raw else _vector(name, roles["temp"][0], raw["temp"])

    columns: list[tuple[str, np.ndarray]] = [(", ".join(roles["acc"]), acc)]
    columns.append((", ".join(roles["gyr"]), gyr))
    if t_raw is not None:
        columns.append((roles["t"][0], t_raw))
    if temp is not None:
        columns.append((roles["temp"][0], temp))
    for var, values in columns:
        if len(values) != n:
            raise IngestError(
                f"has {len(values)} samples but {roles['acc'][0]!r} has {n}; "
                "all variables must have one value per sample",
                file=name,
                field=var,
            )
        _check_finite(name, var, values)

    if t_raw is not None:
        t = _time_to_seconds(name, roles["t"][0], t_raw, time_unit)
    else:
        t = _time_from_rate(name, n, sample_rate_hz)
    dotted = roles["t"][0] if t_raw is not None else "t"
    check_time_increases(t, file=name, sample="sample index", field=dotted)

    return Recording(
        t=t,
        acc=acc if acc_factor == 1.0 else acc * acc_factor,  # no copy of data already in SI
        gyr=gyr if gyr_factor == 1.0 else gyr * gyr_factor,
        temp=temp,
        source=name,
    )


# --- arguments -----------------------------------------------------------------


def _parse_variables(
    name: str, variables: Mapping[str, str | Sequence[str]]
) -> dict[str, list[str]]:
    """Role -> list of dotted MATLAB names (three for a triad given per axis)."""
    if not isinstance(variables, Mapping):
        raise IngestError(
            f"variables must map roles {ROLES} to MATLAB names, got {type(variables).__name__}",
            file=name,
            field="format.variables",
        )
    unknown = sorted(set(variables) - set(ROLES))
    if unknown:
        raise IngestError(
            f"unknown role(s) {unknown}; expected some of {list(ROLES)}",
            file=name,
            field="format.variables",
        )
    roles: dict[str, list[str]] = {}
    for role, spec in variables.items():
        names = [s.strip() for s in spec.split(",")] if isinstance(spec, str) else list(spec)
        ok_count = len(names) in ((1, 3) if role in TRIAD_ROLES else (1,))
        if not ok_count or not all(isinstance(s, str) and s for s in names):
            expected = "one name or three names" if role in TRIAD_ROLES else "one name"
            raise IngestError(
                f"expected {expected} for {role!r}, got {spec!r}",
                file=name,
                field=f"format.variables.{role}",
            )
        roles[role] = names
    for role in TRIAD_ROLES:
        if role not in roles:
            raise IngestError(
                f"no MATLAB variable given for {role!r}",
                file=name,
                field=f"format.variables.{role}",
            )
    return roles


def _unit_factor(name: str, field: str, lookup: Any, unit: str) -> float:
    try:
        return lookup(unit)
    except ValueError as exc:
        raise IngestError(str(exc), file=name, field=field) from None


# --- loading -------------------------------------------------------------------


def _probe(load: Any, name: str, roles: dict[str, list[str]]) -> None:
    """``load(name, roles)`` for its errors only (the arrays stay in the worker process)."""
    load(name, roles)


def _load_mat5(name: str, roles: dict[str, list[str]]) -> dict[str, list[np.ndarray]]:
    """Fetch the arrays of every role from a v5 file (MATLAB orientation, squeezed)."""
    import scipy.io

    _check_mat5_elements(name)
    try:
        held = {var: shape for var, shape, _ in scipy.io.whosmat(name)}
        wanted = sorted({dotted.split(".")[0] for names in roles.values() for dotted in names})
        data = scipy.io.loadmat(
            name, variable_names=[w for w in wanted if w in held], simplify_cells=True
        )
    except Exception as exc:  # scipy raises many types on damaged files
        raise IngestError(f"cannot parse MATLAB v5 file: {exc}", file=name) from None

    def listing() -> str:
        return ", ".join(f"{var} {'x'.join(map(str, shape))}" for var, shape in held.items())

    out: dict[str, list[np.ndarray]] = {}
    for role, names in roles.items():
        out[role] = []
        for dotted in names:
            obj: Any = data
            for depth, part in enumerate(dotted.split(".")):
                if not isinstance(obj, dict) or part not in obj or part.startswith("__"):
                    raise _missing(name, dotted, depth, obj, listing())
                obj = obj[part]
            out[role].append(_numeric(name, dotted, obj))
    return out


def _check_mat5_elements(name: str) -> None:
    """Raise IngestError if a top-level data element runs past the end of the file.

    scipy reads only the variables asked for, so a file cut inside a later
    variable would otherwise pass unnoticed; a cut file is a damaged run.
    """
    miCOMPRESSED = 15
    with open(name, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        f.seek(126)
        order = "<" if f.read(2) == b"IM" else ">"
        pos = 128
        while pos < size:
            f.seek(pos)
            tag = f.read(8)
            if len(tag) < 8:
                raise IngestError(f"truncated: data element tag at byte {pos} is cut", file=name)
            dtype, nbytes = struct.unpack(order + "II", tag)
            if dtype >> 16:  # "small data element": type and size share 4 bytes, data in 4
                pos += 8
                continue
            if pos + 8 + nbytes > size:
                raise IngestError(
                    f"truncated: data element at byte {pos} needs {nbytes} bytes, "
                    f"{size - pos - 8} remain",
                    file=name,
                )
            padded = nbytes if dtype == miCOMPRESSED else (nbytes + 7) // 8 * 8
            pos += 8 + padded


def _load_mat73(name: str, roles: dict[str, list[str]]) -> dict[str, list[np.ndarray]]:
    """Fetch the arrays of every role from a v7.3 (HDF5) file, in MATLAB orientation."""
    import h5py

    try:
        f = h5py.File(name, "r")
    except Exception as exc:  # h5py raises OSError and others on damaged files
        raise IngestError(f"cannot open MATLAB v7.3 (HDF5) file: {exc}", file=name) from None
    with f:

        def listing() -> str:
            items: list[str] = []

            def visit(path: str, obj: Any) -> None:
                if path.startswith("#") or not isinstance(obj, h5py.Dataset):
                    return
                shape = obj.shape[::-1] if "MATLAB_class" in obj.attrs else obj.shape
                items.append(f"{path.replace('/', '.')} {'x'.join(map(str, shape))}")

            with contextlib.suppress(Exception):  # a damaged file: list what could be walked
                f.visititems(visit)
            return ", ".join(items)

        out: dict[str, list[np.ndarray]] = {}
        for role, names in roles.items():
            out[role] = []
            for dotted in names:
                try:
                    out[role].append(_read_h5_variable(name, f, dotted, listing))
                except IngestError:
                    raise
                except Exception as exc:  # damaged datasets surface as assorted errors
                    raise IngestError(
                        f"cannot read variable from HDF5: {exc}", file=name, field=dotted
                    ) from None
        return out


def _read_h5_variable(name: str, f: Any, dotted: str, listing: Any) -> np.ndarray:
    import h5py

    obj = f
    for depth, part in enumerate(dotted.split(".")):
        if not isinstance(obj, h5py.Group) or part not in obj or part.startswith("#"):
            raise _missing(name, dotted, depth, obj, listing())
        obj = obj[part]
    if not isinstance(obj, h5py.Dataset):
        raise IngestError(
            "is a struct (HDF5 group), expected a numeric array; name one of its fields "
            f"({', '.join(f'{dotted}.{k}' for k in obj)})",
            file=name,
            field=dotted,
        )
    mclass = obj.attrs.get("MATLAB_class")
    mclass = mclass.decode() if isinstance(mclass, bytes) else mclass
    if mclass is not None and mclass not in (
        "double",
        "single",
        "logical",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
    ):
        raise IngestError(
            f"has MATLAB class {mclass!r}, expected a numeric array", file=name, field=dotted
        )
    if obj.attrs.get("MATLAB_empty", 0):
        return np.empty(0)
    values = obj[()]
    # MATLAB writes column-major: its (N, 3) is HDF5's (3, N).
    if mclass is not None:
        values = np.transpose(values)
    return _numeric(name, dotted, values)


def _missing(name: str, dotted: str, depth: int, parent: Any, listing: str) -> IngestError:
    head = ".".join(dotted.split(".")[:depth]) or "the file"
    return IngestError(
        f"variable {dotted!r} not found (no {dotted.split('.')[depth]!r} in {head}); "
        f"the file holds: {listing or 'no variables'}",
        file=name,
        field=dotted,
    )


def _numeric(name: str, dotted: str, obj: Any) -> np.ndarray:
    """`obj` as a squeezed float64 array, or IngestError if it is not numeric."""
    if isinstance(obj, dict):
        fields = ", ".join(f"{dotted}.{k}" for k in obj)
        raise IngestError(
            f"is a struct, expected a numeric array; name one of its fields ({fields})",
            file=name,
            field=dotted,
        )
    values = np.asarray(obj)
    if values.dtype.kind not in _NUMERIC_KINDS:
        raise IngestError(
            f"holds {values.dtype} data (a cell, char or struct array?), expected numbers",
            file=name,
            field=dotted,
        )
    return np.squeeze(values)


# --- shaping and checks -------------------------------------------------------------


def _vector(name: str, dotted: str, arrays: list[np.ndarray]) -> np.ndarray:
    values = np.atleast_1d(arrays[0])
    if values.ndim != 1:
        raise IngestError(
            f"has shape {values.shape}, expected a vector (one value per sample)",
            file=name,
            field=dotted,
        )
    return values


def _triad(name: str, names: list[str], arrays: list[np.ndarray], n: int | None) -> np.ndarray:
    """(N, 3) float64 from one (N, 3)/(3, N) array or three vectors."""
    if len(arrays) == 3:
        columns = [_vector(name, dotted, [a]) for dotted, a in zip(names, arrays, strict=True)]
        for dotted, col in zip(names[1:], columns[1:], strict=True):
            if len(col) != len(columns[0]):
                raise IngestError(
                    f"has {len(col)} samples but {names[0]!r} has {len(columns[0])}",
                    file=name,
                    field=dotted,
                )
        return np.column_stack(columns).astype(np.float64, copy=False)
    values = np.atleast_2d(arrays[0])
    dotted = names[0]
    if values.ndim == 2 and values.shape[1] == 3 and (n is None or values.shape[0] == n):
        return values.astype(np.float64, copy=False)
    if values.ndim == 2 and values.shape[0] == 3:
        return values.T.astype(np.float64, copy=False)
    if values.ndim == 2 and values.shape[1] == 3:
        return values.astype(np.float64, copy=False)  # length mismatch is reported later
    raise IngestError(
        f"has shape {values.shape}, expected (N, 3) or (3, N)", file=name, field=dotted
    )


def _check_finite(name: str, dotted: str, values: np.ndarray) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        row = int(np.flatnonzero(bad.reshape(len(values), -1).any(axis=1))[0])
        raise IngestError(
            f"non-finite value ({values[row]}) at sample index {row} (0-based)",
            file=name,
            field=dotted,
        )


def _time_to_seconds(name: str, dotted: str, raw: np.ndarray, unit: str) -> np.ndarray:
    """Seconds from `raw` time values; offsets from the first sample are formed before scaling."""
    if len(raw) == 0:
        return raw.astype(np.float64)
    first = raw[0]
    if raw.dtype.kind in "iub":
        rel = (raw.astype(np.int64) - np.int64(first)).astype(np.float64)
    else:
        rel = raw.astype(np.float64) - np.float64(first)
    if unit == "datenum":
        return (float(first) - DATENUM_UNIX_EPOCH) * SECONDS_PER_DAY + rel * SECONDS_PER_DAY
    factor = time_factor(unit)
    return float(first) * factor + rel * factor


def _time_from_rate(name: str, n: int, sample_rate_hz: float | None) -> np.ndarray:
    if sample_rate_hz is None or not np.isfinite(sample_rate_hz) or sample_rate_hz <= 0:
        raise IngestError(
            f"no time variable and no valid sample rate ({sample_rate_hz!r}); give "
            "variables['t'] or a positive sample_rate_hz",
            file=name,
            field="format.sample_rate_hz",
        )
    return np.arange(n, dtype=np.float64) / float(sample_rate_hz)
