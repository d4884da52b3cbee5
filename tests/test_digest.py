"""The set digest's file hashes: every byte counts, the hash is named, and a file is
read in blocks (a large frame costs no more memory than one block)."""
from __future__ import annotations

import hashlib

import pytest

from hdrcl.shoot.batch import state


def test_every_byte_of_the_file_counts_and_the_hash_is_named(tmp_path):
    a = tmp_path / "a.jpg"
    data = bytearray(b"\xff\xd8" + bytes(range(256)) * 50_000)  # 12.8 MB: several blocks
    a.write_bytes(bytes(data))
    first = state._file_digest(str(a))
    name, _, hexd = first.partition(":")
    assert name in ("xxh3-128", "sha256") and len(hexd) == 32 * (2 if name == "sha256" else 1)
    data[-1] ^= 1  # the last byte of the last block
    a.write_bytes(bytes(data))
    assert state._file_digest(str(a)) != first
    b = tmp_path / "moved" / "a.jpg"
    b.parent.mkdir()
    b.write_bytes(bytes(data))
    assert state._file_digest(str(b)) == state._file_digest(str(a))  # content, not place


def test_sha256_is_what_it_says_without_xxhash(tmp_path, monkeypatch):
    import builtins

    real = builtins.__import__

    def no_xxhash(name, *args, **kw):
        if name == "xxhash":
            raise ImportError(name)
        return real(name, *args, **kw)

    monkeypatch.setattr(builtins, "__import__", no_xxhash)
    a = tmp_path / "a.jpg"
    a.write_bytes(b"\x00" * (state.HASH_BLOCK + 17))
    assert state._file_digest(str(a)) == "sha256:" + hashlib.sha256(a.read_bytes()).hexdigest()


def test_xxh3_when_installed(tmp_path):
    xxhash = pytest.importorskip("xxhash")
    a = tmp_path / "a.jpg"
    a.write_bytes(b"\x01" * (2 * state.HASH_BLOCK + 5))
    assert state._file_digest(str(a)) == "xxh3-128:" + xxhash.xxh3_128(a.read_bytes()).hexdigest()
