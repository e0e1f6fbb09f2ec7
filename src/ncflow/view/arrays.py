"""Arrays in the page of ``ncflow view``: packed for the page's script (:func:`encode_array`, read back by
:func:`decode_array` as the script decodes them) and positions quantised to 16 bits in their box.
"""

from __future__ import annotations

import base64
import zlib
from typing import Any

import numpy as np
from jaxtyping import Float

__all__ = ["DTYPES", "QUANT_LEVELS", "decode_array", "dequantize_positions", "encode_array", "quantize_positions"]

QUANT_LEVELS = 65535
"""uint16 quantisation levels of positions."""
DTYPES = {"uint8": "<u1", "uint16": "<u2", "uint32": "<u4", "float32": "<f4"}
"""The page's array types and their little-endian NumPy codes."""


def encode_array(array: np.ndarray, dtype: str, *, delta: bool = False) -> dict[str, Any]:
    """``{"dtype", "shape", "delta", "codec", "data"}``: an array packed for the page.

    The values are cast to ``dtype`` (little-endian); with ``delta`` (unsigned integers only) each
    row along the first axis is replaced by its difference from the previous row, modulo 2^bits
    (frames of a smooth motion differ little); the bytes are split into planes (every value's first
    byte, then every second byte: the HDF5 "shuffle" filter), deflated (zlib) and base64-encoded.
    The page inflates them with the browser's own ``DecompressionStream``. Measured on 20 frames
    of a 50k-vertex result: 2.3× smaller than the raw uint16 bytes.

    Args:
        array: any shape; values must fit ``dtype`` (checked by the caller).
        dtype: ``"uint8"``, ``"uint16"``, ``"uint32"`` or ``"float32"``.
        delta: difference-code along the first axis.
    """
    a = np.ascontiguousarray(np.asarray(array).astype(DTYPES[dtype]))
    if delta:
        if a.dtype.kind != "u" or a.ndim == 0:
            raise ValueError("delta coding needs an unsigned integer array with a first axis")
        d = a.copy()
        d[1:] = a[1:] - a[:-1]  # unsigned: wraps modulo 2**bits, undone by a wrapping running sum
        a = d
    planes = np.frombuffer(a.tobytes(), np.uint8).reshape(-1, a.itemsize).T.tobytes()
    return {
        "dtype": dtype,
        "shape": list(a.shape),
        "delta": bool(delta),
        "codec": "shuffle-deflate",
        "data": base64.b64encode(zlib.compress(planes, 6)).decode("ascii"),
    }


def decode_array(spec: dict[str, Any]) -> np.ndarray:
    """The array of :func:`encode_array` (what the page's script decodes)."""
    dtype = np.dtype(DTYPES[spec["dtype"]])
    shape = tuple(int(n) for n in spec["shape"])
    planes = np.frombuffer(zlib.decompress(base64.b64decode(spec["data"], validate=True)), np.uint8)
    a = np.ascontiguousarray(planes.reshape(dtype.itemsize, -1).T).view(dtype).reshape(shape)
    if spec.get("delta"):
        a = np.cumsum(a, axis=0, dtype=dtype)  # wraps modulo 2**bits like the encoder
    return a


def quantize_positions(
    points: Float[np.ndarray, "... 3"], lo: Float[np.ndarray, " 3"], hi: Float[np.ndarray, " 3"]
) -> np.ndarray:
    """Points as uint16 per axis in the box [lo, hi]: round((p − lo) / (hi − lo) · 65535).

    The error is at most half a step, (hi − lo) / 131070 per axis (a flat axis maps to 0).
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    span = np.where(hi > lo, hi - lo, 1.0)
    q = np.rint((np.asarray(points, np.float64) - lo) / span * QUANT_LEVELS)
    return np.clip(q, 0, QUANT_LEVELS).astype(np.uint16)


def dequantize_positions(
    q: np.ndarray, lo: Float[np.ndarray, " 3"], hi: Float[np.ndarray, " 3"]
) -> Float[np.ndarray, "... 3"]:
    """The inverse of :func:`quantize_positions` (what the page's script computes)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return lo + np.asarray(q, np.float64) * ((hi - lo) / QUANT_LEVELS)
