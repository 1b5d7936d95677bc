"""The checksums of a case's data (format 5 on): 64-bit BLAKE2b of an array's bytes as stored."""
from __future__ import annotations

import hashlib

import numpy as np


def digest(values) -> int:
    """The 64-bit BLAKE2b checksum of an array's bytes (as stored: float64 or int64, little-endian)."""
    return int.from_bytes(hashlib.blake2b(_digest_bytes(values), digest_size=8).digest(), "little")


def _digest_bytes(values) -> np.ndarray:
    """The array whose bytes (C order, little-endian) :func:`digest` hashes (rows hashed one batch after
    another give the digest of them all)."""
    data = np.ascontiguousarray(values)
    if data.dtype.byteorder == ">" or (data.dtype.byteorder == "=" and np.little_endian is False):
        data = data.astype(data.dtype.newbyteorder("<"))
    return data                        # hashlib reads a C-contiguous array's buffer: its bytes in C order
