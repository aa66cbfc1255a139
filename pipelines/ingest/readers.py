"""The reader of each ``[format] kind`` of a run manifest: a registry, and adapters.

An adapter turns the manifest's [format] section into its reader's arguments. A new
format only needs ``register_reader(kind, fn)`` with ``fn(path, fmt) -> Recording``;
readers of heavy formats live in modules of their own, imported on first use.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path

from calib_core.recording import Recording
from pipelines.ingest.csv_reader import read_csv
from pipelines.ingest.data_format import FormatSpec, extra_keys, format_dict, format_spec
from pipelines.ingest.errors import IngestError
from pipelines.ingest.mpu6000 import read_mpu6000_file

Reader = Callable[[Path, FormatSpec], Recording]
_READERS: dict[str, Reader] = {}
# Readers that live in modules of their own, imported on first use. Such a
# module calls register_reader() when imported, unless an adapter is given here.
_PLUGIN_MODULES = {"mat": "pipelines.ingest.matlab", "mcap": "pipelines.ingest.mcap_reader"}


def register_reader(kind: str, reader: Reader) -> None:
    """Make `reader(path, fmt) -> Recording` the reader of files with ``format.kind == kind``."""
    _READERS[kind] = reader


def _read_mat(path: Path, fmt: FormatSpec) -> Recording:
    """Adapter from the manifest's [format] (``variables``, ``sample_rate_hz``) to read_mat."""
    from pipelines.ingest.matlab import read_mat

    extra = fmt.extra
    if "variables" not in extra:
        raise IngestError(
            "format kind 'mat' needs a [format.variables] table (t, acc, gyr, temp)",
            field="format.variables",
        )
    return read_mat(
        path,
        variables=extra["variables"],
        time_unit=fmt.time_unit,
        acc_unit=fmt.acc_unit,
        gyr_unit=fmt.gyr_unit,
        sample_rate_hz=fmt.sample_rate_hz,
    )


def _read_mcap(path: Path, fmt: FormatSpec) -> Recording:
    """Adapter from the manifest's [format] (``imu_topic``, ``stamp``, ...) to read_mcap.

    MCAP messages carry SI units by the ROS conventions, so the unit fields
    of [format] do not apply; every key is optional (one Imu topic is found
    by its schema).
    """
    from pipelines.ingest.mcap_reader import KEYS, read_mcap

    return read_mcap(path, **extra_keys(fmt, "mcap", KEYS))


def _read_ulog(path: Path, fmt: FormatSpec) -> Recording:
    """Adapter of [format] ``source``, ``instance``, ``min_rate_hz`` to read_ulog (units: PX4's
    SI)."""
    from pipelines.ingest.ulog_reader import read_ulog

    return read_ulog(path, **extra_keys(fmt, "ulog", ("source", "instance", "min_rate_hz")))


def _read_dataflash(path: Path, fmt: FormatSpec) -> Recording:
    """Adapter of [format] ``instance``, ``min_rate_hz`` to read_dataflash (units: ArduPilot's
    SI)."""
    from pipelines.ingest.dataflash_reader import read_dataflash

    return read_dataflash(path, **extra_keys(fmt, "dataflash", ("instance", "min_rate_hz")))


def _read_rosbag(path: Path, fmt: FormatSpec) -> Recording:
    """Adapter of [format] topics to read_rosbag (ROS 1 .bag or ROS 2 .db3, by content)."""
    from pipelines.ingest.rosbag_reader import KEYS, read_rosbag

    return read_rosbag(path, **extra_keys(fmt, "rosbag", KEYS))


register_reader("csv", read_csv)
register_reader("ulog", _read_ulog)
register_reader("dataflash", _read_dataflash)
register_reader("rosbag", _read_rosbag)
register_reader("mpu6000", lambda path, fmt: read_mpu6000_file(path))
register_reader("mat", _read_mat)
register_reader("mcap", _read_mcap)


# imu_tk's text files: "t x y z" per line, whitespace-separated, no header, one file per
# sensor (segments give acc_file and gyr_file) or one file for both.
IMUTK_DEFAULTS = {
    "header": False,
    "delimiter": "whitespace",
    "time_column": 0,
    "acc_columns": [1, 2, 3],
    "gyr_columns": [1, 2, 3],
}


def imutk_format(fmt: FormatSpec) -> FormatSpec:
    """The CSV [format] of imu_tk text: `IMUTK_DEFAULTS` under the manifest's own fields."""
    return format_spec({**IMUTK_DEFAULTS, **format_dict(fmt, given_only=True), "kind": "csv"})


def reader_for(kind: str) -> Reader:
    """The registered reader of `kind`, importing its module on first use."""
    if kind not in _READERS and kind in _PLUGIN_MODULES:
        try:
            importlib.import_module(_PLUGIN_MODULES[kind])
        except ModuleNotFoundError as exc:
            if exc.name != _PLUGIN_MODULES[kind]:  # a broken plugin must not pass unnoticed
                raise
    if kind not in _READERS:
        raise IngestError(
            f"no reader for format kind '{kind}' (readers: {', '.join(sorted(_READERS))})",
            field="format.kind",
        )
    return _READERS[kind]
