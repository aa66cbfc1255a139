"""A ROS 1 bag cut while written, read to its last whole record (`rosbag_reader.open_bag`).

A bag's index (its connections and chunk list) is written after its last chunk, when the
recording ends cleanly; a recorder that lost power leaves the bag header pointing past
the end of the file (``index_pos`` beyond it, or 0: never written), an index with fewer
records than the header lists, or a last record cut short. `whole_records` walks the top-
level records by their lengths to the first one the file cuts short; `CutBagReader` is
rosbags' reader with its index rebuilt from the whole chunks' own records (connection and
message records, as ``rosbag reindex`` does), so the messages of every whole chunk are
read as from an intact bag and the bytes from the cut record on are dropped with the
``record:cut:<file>`` finding (`log_samples.cut_tail`). A whole chunk that does not
decompress or whose records do not follow each other is damage inside the bag, refused
naming its byte offset.
"""

from __future__ import annotations

import io
import os
import struct
from collections import defaultdict
from pathlib import Path

from rosbags.rosbag1.reader import (
    Chunk,
    Header,
    IndexData,
    Reader,
    ReaderError,
)

from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import cut_tail

OP_MSGDATA, OP_CHUNK, OP_CONNECTION = 2, 5, 7
MAGIC_SIZE = 13  # b"#ROSBAG V2.0\n"


def whole_records(path: Path) -> tuple[int, int, bool]:
    """(end, size, indexed): the byte where the first top-level record the file cuts short
    starts (`size` when none is), the file's size, and whether the bag holds its whole
    index (``index_pos`` inside the file, followed by as many whole records as the bag
    header's ``conn_count`` + ``chunk_count``). Only the records' length fields are read."""
    size = os.path.getsize(path)
    with Path(path).open("rb") as fh:
        fh.seek(MAGIC_SIZE)
        header = Header.read(fh)
        index_pos = header.get_uint64("index_pos")
        listed = header.get_uint32("conn_count") + header.get_uint32("chunk_count")
        pos = fh.tell()
        (padding,) = struct.unpack("<I", fh.read(4))
        pos += 4 + padding
        in_index = 0  # whole records from index_pos on
        while pos < size:
            fh.seek(pos)
            head = fh.read(4)
            if len(head) < 4 or pos + 8 + (hlen := struct.unpack("<I", head)[0]) > size:
                break
            fh.seek(hlen, os.SEEK_CUR)
            (dlen,) = struct.unpack("<I", fh.read(4))
            if pos + 8 + hlen + dlen > size:
                break
            in_index += 0 < index_pos <= pos
            pos += 8 + hlen + dlen
    return pos, size, pos == size and 0 < index_pos < size and in_index >= listed


def is_cut(path: Path) -> bool:
    """Whether the bag lacks its whole index (`whole_records`): cut while written."""
    return not whole_records(path)[2]


class CutBagReader(Reader):
    """rosbags' ROS 1 reader of a bag without its index: the index rebuilt from the whole
    chunks; ``findings`` holds its ``record:cut:<file>`` finding."""

    findings: tuple[dict, ...] = ()

    def open(self) -> None:
        end, size, _ = whole_records(self.path)
        # no index is a bag cut while written, even at a record boundary (0 bytes dropped)
        self.findings = (cut_tail(self.path, "ROS 1 bag", end, size - end, size),)
        self.bio = self.path.open("rb")
        try:
            self._rebuild(end)
        except BaseException:
            self.bio.close()
            self.bio = None
            raise

    def _rebuild(self, end: int) -> None:
        """Connections, chunks and message index from the records before byte `end`."""
        self.bio.seek(MAGIC_SIZE)
        Header.read(self.bio)
        self.bio.seek(struct.unpack("<I", self.bio.read(4))[0], os.SEEK_CUR)
        connections, indexes = {}, defaultdict(list)
        self.chunks, self.chunk_infos = {}, []
        while self.bio.tell() < end:
            pos = self.bio.tell()
            try:
                header = Header.read(self.bio)
                length = struct.unpack("<I", self.bio.read(4))[0]
                following = self.bio.tell() + length
                op = header.get_uint8("op")
                self.bio.seek(pos)
                if op == OP_CONNECTION:
                    conn = self.read_connection()
                    connections.setdefault(conn.id, conn)
                elif op == OP_CHUNK:
                    self.chunks[pos] = self.read_chunk()
            except (ReaderError, struct.error) as exc:
                raise IngestError(
                    f"damaged ROS 1 bag: the record at byte offset {pos} does not parse ({exc})",
                    file=self.path,
                ) from None
            if op == OP_CHUNK:
                self._chunk_records(pos, self.chunks[pos], connections, indexes)
            self.bio.seek(following)  # index data, chunk info: rebuilt from the chunks
        self.indexes = {c: sorted(indexes[c]) for c in connections}
        self.connections = [
            c._replace(msgcount=len(self.indexes[c.id])) for c in connections.values()
        ]

    def _chunk_records(self, pos: int, chunk: Chunk, connections: dict, indexes) -> None:
        """The connection and message records of the whole chunk at byte `pos`."""
        try:
            self.bio.seek(chunk.datapos)
            data = chunk.decompressor(self.bio.read(chunk.datasize))
        except Exception as exc:  # a damaged compressed block
            raise IngestError(
                f"damaged ROS 1 bag: the chunk at byte offset {pos} does not decompress "
                f"({type(exc).__name__}: {exc})",
                file=self.path,
            ) from None
        buf, outer = io.BytesIO(data), self.bio
        try:
            while buf.tell() < len(data):
                at = buf.tell()
                header = Header.read(buf)
                length = struct.unpack("<I", buf.read(4))[0]
                if header.get_uint8("op") == OP_CONNECTION:
                    buf.seek(at)
                    self.bio = buf
                    conn = self.read_connection()
                    connections.setdefault(conn.id, conn)
                    continue
                if header.get_uint8("op") == OP_MSGDATA:
                    conn_id = header.get_uint32("conn")
                    if conn_id not in connections:
                        raise ReaderError(f"a message of connection {conn_id}, never defined")
                    indexes[conn_id].append(IndexData(header.get_time("time"), pos, at))
                buf.seek(length, os.SEEK_CUR)
            if buf.tell() != len(data):
                raise ReaderError("a record runs past the chunk's end")
        except (ReaderError, struct.error) as exc:
            raise IngestError(
                f"damaged ROS 1 bag: the records of the chunk at byte offset {pos} do not "
                f"follow each other ({exc})",
                file=self.path,
            ) from None
        finally:
            self.bio = outer
