"""MIMO plants and loops the MIMO verification tests share."""

from __future__ import annotations

import numpy as np

from gaintune.lti.mimo import DelayedSS, TfEntry, TfMatrix
from gaintune.verification.mimo_loop import LoopPair, PidLoop


def entry(num, den, delay=0.0) -> TfEntry:
    """One transfer-function entry."""
    return TfEntry(np.array(num, float), np.array(den, float), delay)


def wood_berry() -> TfMatrix:
    """The Wood-Berry column (minutes): outputs xD, xB; inputs reflux, steam."""
    return TfMatrix(((entry([12.8], [16.7, 1], 1), entry([-18.9], [21, 1], 3)),
                     (entry([6.6], [10.9, 1], 7), entry([-19.4], [14.4, 1], 3))),
                    inputs=("reflux", "steam"), outputs=("xD", "xB"))


def blt_loops(factor: float = 1.0) -> list[PidLoop]:
    """Luyben's BLT PI tuning of Wood-Berry (Kc 0.375, Ti 8.29; Kc -0.075, Ti 23.6), gains times ``factor``."""
    k1, k2 = 0.375 * factor, -0.075 * factor
    return [PidLoop("top", "xD", "reflux", Kp=k1, Ki=k1 / 8.29), PidLoop("bottom", "xB", "steam", Kp=k2, Ki=k2 / 23.6)]


def satellite(a: float = 10.0) -> DelayedSS:
    """The spinning satellite (MathWorks diskmargin example; Skogestad and Postlethwaite, Example 3.11)."""
    return DelayedSS(np.array([[0.0, a], [-a, 0.0]]), np.eye(2), np.array([[1.0, a], [-a, 1.0]]), np.zeros((2, 2)),
                     inputs=("u1", "u2"), outputs=("y1", "y2"))


def static_controller(K) -> DelayedSS:
    """A static 2 x 2 controller u = K e."""
    return DelayedSS(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((2, 0)), np.array(K, float),
                     inputs=("y1", "y2"), outputs=("u1", "u2"))


PAIRS = [LoopPair("l1", "y1", "u1"), LoopPair("l2", "y2", "u2")]


def diagonal_plant() -> TfMatrix:
    """Two decoupled loops: 1/(s+1)^3 and 2/(s^2 + 0.6 s + 1)(0.5 s + 1)."""
    z = entry([0.0], [1.0])
    return TfMatrix(((entry([1], [1, 3, 3, 1]), z), (z, entry([2], np.polymul([1, 0.6, 1], [0.5, 1])))),
                    inputs=("u1", "u2"), outputs=("y1", "y2"))


