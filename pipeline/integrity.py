"""Digests of stored chunks: recorded as they are written, checked as they are read.

The metadata decides what a reader gets as much as the chunks do (a codec's endianness turns every value into
garbage), so the commit also records the digest of every ``zarr.json`` (the group's, with its attributes, and each
array's), and reads and `mocapflow verify` check them like chunks.

Every chunk a region write stores is recorded as ``"<bytes>:<crc32c>"`` of its stored (compressed) bytes, keyed
by its zarr key (``value/c/0/4/0/0``), in the region's marker; the commit gathers them into ``digests.json``.
A read checks each chunk it fetches against its record, so a chunk that was deleted (zarr would read fill
values), truncated, altered or copied over another is an IntegrityError naming the version, the array and the
chunk, before any decoding. zarr's own crc32c codec would catch the altered and truncated chunks only: a
missing chunk reads as fill values and a chunk copied over another carries a valid checksum. CRC-32C (the
``google-crc32c`` package zarr depends on) runs at several GB/s; it is for accidental damage, not tampering.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

import google_crc32c
import numpy as np
from zarr.abc.store import ByteRequest
from zarr.core.buffer import Buffer, BufferPrototype
from zarr.storage import FsspecStore, LocalStore, WrapperStore

from mocapflow.pipeline.errors import IntegrityError


def digest(data) -> str:
    """``"<length>:<crc32c hex>"`` of a bytes-like object."""
    raw = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1).view(np.uint8)
    return f"{raw.nbytes}:{google_crc32c.value(raw):08x}"


def buffer_digest(value: Buffer) -> str:
    return digest(value.as_numpy_array())


def is_chunk(key: str) -> bool:
    """Whether a zarr v3 key names a chunk (``<array>/c/...``), not metadata."""
    return key.startswith("c/") or "/c/" in key


def array_of(key: str) -> str:
    return key.split("/c/", 1)[0] if "/c/" in key else ""


def zarr_store(target: str, read_only: bool):
    """The zarr store of a local path or an fsspec URL."""
    if "://" in target:
        return FsspecStore.from_url(target, read_only=read_only)
    return LocalStore(target, read_only=read_only)


class RecordingStore(WrapperStore):
    """Records the digest of every chunk written through it in ``digests`` (key -> digest)."""

    def __init__(self, store, digests: dict[str, str]):
        super().__init__(store)
        self.digests = digests

    def _with_store(self, store):
        return type(self)(store, self.digests)

    async def set(self, key: str, value: Buffer) -> None:
        await self._store.set(key, value)
        if is_chunk(key):
            self.digests[key] = buffer_digest(value)

    async def _set_many(self, values: Iterable[tuple[str, Buffer]]) -> None:
        for key, value in values:
            await self.set(key, value)


@dataclass(frozen=True)
class Where:
    """What a verified store holds, for messages: ``stage``/``key`` (partition ``partition``) under ``root``."""

    stage: str
    key: str
    partition: str
    root: str

    def damaged(self, chunk: str, problem: str) -> IntegrityError:
        what = f"chunk {chunk} of array {array_of(chunk)!r}" if is_chunk(chunk) else f"metadata {chunk}"
        return IntegrityError(
            f"artifact {self.stage}/{self.key} (partition {self.partition}) in {self.root}: {what} {problem}; the "
            f"stored data changed after it was committed: run `mocapflow verify {self.stage}` to mark the damaged "
            f"versions, then `mocapflow run` to recompute them")


def chunk_problem(data, want: str) -> str | None:
    """What is wrong with the stored bytes ``data`` (None: missing) of a chunk recorded as ``want``, or None."""
    if data is None:
        return f"is missing (recorded {want})"
    got = digest(data)
    return None if got == want else f"has digest {got}, recorded {want}"


def check_chunk(where: Where, key: str, data, want: str) -> None:
    """IntegrityError unless the stored bytes ``data`` (None: missing) match the recorded digest ``want``."""
    problem = chunk_problem(data, want)
    if problem is not None:
        raise where.damaged(key, problem)


class VerifyingStore(WrapperStore):
    """Checks every recorded chunk read through it against ``expected`` (key -> digest)."""

    def __init__(self, store, expected: dict[str, str], where: Where):
        super().__init__(store)
        self.expected, self.where = expected, where

    def _with_store(self, store):
        return type(self)(store, self.expected, self.where)

    async def get(self, key: str, prototype: BufferPrototype, byte_range: ByteRequest | None = None) -> Any:
        value = await self._store.get(key, prototype, byte_range)
        want = self.expected.get(key)
        if want is not None and byte_range is None:
            check_chunk(self.where, key, None if value is None else value.as_numpy_array(), want)
        return value
