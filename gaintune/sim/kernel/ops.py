"""Scalar primitives of the kernel: vectorisable min/max and the counter-based normal draw."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, inline="always")
def _max(a, b):
    """``max(a, b)`` exactly as numba's builtin, but as a plain select that LLVM can vectorise."""
    return b if b > a else a


@nb.njit(cache=True, inline="always")
def _min(a, b):
    """``min(a, b)`` exactly as numba's builtin, but as a plain select that LLVM can vectorise."""
    return b if b < a else a


@nb.njit(cache=True)
def _normal(seed: np.int64, k: np.int64, lane: np.int64) -> float:
    """Counter-based standard normal (splitmix64 hash + Box-Muller): reproducible per candidate."""
    z = np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(k) * np.uint64(0xBF58476D1CE4E5B9)
    z = z + np.uint64(lane) * np.uint64(0x94D049BB133111EB) + np.uint64(0x632BE59BD9B4E019)
    z1 = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z1 = (z1 ^ (z1 >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z1 = z1 ^ (z1 >> np.uint64(31))
    z2 = (z1 + np.uint64(0x9E3779B97F4A7C15)) * np.uint64(0xBF58476D1CE4E5B9)
    z2 = z2 ^ (z2 >> np.uint64(31))
    u1 = (float(z1 >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
    u2 = float(z2 >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)
