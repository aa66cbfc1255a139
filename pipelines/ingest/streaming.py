"""The streamed readers: one function per source format, all returning `Streamed`.

A streamed reader reads one data file once, in blocks bounded by a memory limit: it
hashes and copies its bytes (the raw copy), writes its samples to the samples' Parquet
and keeps the first-pass statistics of a static record. `calib process` takes this
route for a static-bias run whose recording is larger than the run's memory limit
(`STREAMERS[kind]` with the [format] section's kind).

Every streamer has the signature of `pipelines.ingest.csv_reader.stream_csv` and runs its
format's reader through `pipelines.ingest.streamed_pass`::

    stream(path: Path, fmt: FormatSpec, samples: Path,
           **options: Unpack[StreamOptions]) -> Streamed

(`pipelines.ingest.streamed_pass.StreamOptions`: copy_to, label, memory_limit, progress,
window)

and returns a `Streamed` (`pipelines.ingest.streamed_pass.Streamed`):

- ``sha256`` : hex SHA-256 of the file's bytes, all of them, as read;
- ``size`` : the file's size, bytes;
- ``samples`` : the Parquet file written (`storage.rawstore.samples_parquet_options`;
  columns ``segment`` (string, ``label`` on every row), ``t`` (s), ``acc_x..acc_z``
  (m/s^2), ``gyr_x..gyr_z`` (rad/s), ``temp`` (deg C, NaN where none), all float64 in SI,
  time strictly increasing);
- ``first`` : `calib_core.solvers.static_bias.FirstPass` pushed with every chunk
  in order, ``first.push((t, gyr, acc))``;
- ``seconds`` : wall time of the pass, s.

Bad input raises `pipelines.ingest.errors.IngestError` naming the file and, where it can,
the line/message and field.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass

from calib_core.streamed import RecordSummary
from pipelines.ingest.csv_reader import stream_csv
from pipelines.ingest.mcap_reader import stream_mcap
from pipelines.ingest.rosbag_reader import stream_rosbag
from pipelines.ingest.streamed_pass import DEFAULT_MEMORY_LIMIT, Streamed
from storage.rawstore import SamplesFile

Streamer = Callable[..., Streamed]

# The [format] section's kind -> its streamed reader.
STREAMERS: dict[str, Streamer] = {
    "csv": stream_csv,
    "mcap": stream_mcap,
    "rosbag": stream_rosbag,  # ROS 1 bags; a ROS 2 .db3 is refused with the reason
}


@dataclass
class StreamedRecord:
    """A run's one record as the streamed route keeps it (`LoadedRun.streamed`).

    label : the segment's label.
    result : what the streamer's pass gave (hash, size, samples' Parquet, statistics).
    samples_sha256 : the SHA-256 of the samples' Parquet, hashed in a thread meanwhile.
    memory_limit : bytes, the run's limit.
    summary : what the conditions take of the record; set by the solve's pass.
    """

    label: str
    result: Streamed
    samples_sha256: Future[str]
    memory_limit: int
    summary: RecordSummary | None = None

    @property
    def samples(self) -> SamplesFile:
        """The samples' Parquet as the archive takes it (path and SHA-256)."""
        return SamplesFile(self.result.samples, self.samples_sha256.result())

    @property
    def n(self) -> int:
        """Samples in the record."""
        return self.result.first.n


__all__ = ["DEFAULT_MEMORY_LIMIT", "STREAMERS", "StreamedRecord", "Streamed", "Streamer"]
