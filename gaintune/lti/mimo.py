"""MIMO linear plants with delays: the one representation every MIMO layer shares.

Two forms, both with named inputs and outputs:

* :class:`TfMatrix`: a p x m matrix of SISO entries ``num/den * e^{-s*delay}``, each with its own
  delay (the Wood-Berry form). A zero entry has ``num == [0]``.
* :class:`DelayedSS`: ``dx/dt = A x + B u(t - input_delays)``, ``y = C x + D u``, one delay per
  input column (and per output row).

Both give the frequency response :meth:`freqresp` (``(len(w), p, m)`` complex, exact delays) and a
delay-free realisation with Padé approximants of the delays, :meth:`pade_ss`, for eigenvalues.
Nothing here knows about specs, loops or controllers: it imports only numpy and :mod:`.pade`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gaintune.lti.pade import canonical_form, pade_ss

__all__ = ["TfEntry", "TfMatrix", "DelayedSS", "MimoLti", "block_diag"]


def block_diag(*blocks: np.ndarray) -> np.ndarray:
    """Block-diagonal stack of 2-D arrays (empty blocks allowed)."""
    rows = sum(b.shape[0] for b in blocks)
    cols = sum(b.shape[1] for b in blocks)
    out = np.zeros((rows, cols))
    r = c = 0
    for b in blocks:
        out[r:r + b.shape[0], c:c + b.shape[1]] = b
        r, c = r + b.shape[0], c + b.shape[1]
    return out


@dataclass(frozen=True)
class TfEntry:
    """One SISO entry ``num(s)/den(s) * e^{-s delay}`` (descending powers of s, proper)."""

    num: np.ndarray
    den: np.ndarray
    delay: float = 0.0

    @property
    def is_zero(self) -> bool:
        """Whether the entry is identically zero."""
        return not np.any(self.num)

    def response(self, s: np.ndarray) -> np.ndarray:
        """The entry evaluated at the complex points ``s``, exact delay."""
        if self.is_zero:
            return np.zeros_like(s, dtype=complex)
        return np.polyval(self.num, s) / np.polyval(self.den, s) * np.exp(-s * self.delay)

    def dcgain(self) -> float:
        """Static gain num(0)/den(0) (inf for an integrating entry)."""
        if self.is_zero:
            return 0.0
        d = self.den[-1]
        return float(self.num[-1] / d) if d != 0 else float(np.sign(self.num[-1]) * np.inf)

    def realisation(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C, D) of the delay-free part in controller canonical form (empty A for a zero/static entry)."""
        if self.is_zero:
            return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.zeros((1, 1))
        return canonical_form(np.asarray(self.num, float), np.asarray(self.den, float))


def _cascade_delay(abcd: tuple, delay: float, order: int) -> tuple:
    """(A, B, C, D) of ``abcd`` with the Padé approximant of e^{-s delay} at its input."""
    if delay <= 0 or order <= 0:
        return abcd
    A, B, C, D = abcd
    Ap, Bp, Cp, Dp = pade_ss(delay, order)
    Dp = np.atleast_2d(Dp)
    n, k = A.shape[0], Ap.shape[0]
    Ac = np.block([[A, B @ Cp], [np.zeros((k, n)), Ap]])
    Bc = np.vstack([B @ Dp, Bp])
    Cc = np.hstack([C, D @ Cp])
    return Ac, Bc, Cc, D @ Dp


@dataclass(frozen=True)
class TfMatrix:
    """A p x m transfer-function matrix with a delay per entry.

    Parameters
    ----------
    entries
        ``entries[i][j]`` maps input j to output i.
    inputs, outputs
        Names of the m inputs and p outputs.
    """

    entries: tuple[tuple[TfEntry, ...], ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]

    @property
    def shape(self) -> tuple[int, int]:
        """(p outputs, m inputs)."""
        return len(self.entries), len(self.entries[0])

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        """G(jw), ``(len(w), p, m)`` complex, exact delays."""
        s = 1j * np.asarray(w, dtype=float)
        p, m = self.shape
        out = np.empty((s.size, p, m), dtype=complex)
        for i in range(p):
            for j in range(m):
                out[:, i, j] = self.entries[i][j].response(s)
        return out

    def dcgain(self) -> np.ndarray:
        """(p, m) static gains."""
        return np.array([[e.dcgain() for e in row] for row in self.entries])

    def pade_ss(self, order: int = 4) -> DelayedSS:
        """A delay-free (non-minimal, entry-by-entry) realisation, delays replaced by Padé approximants."""
        p, m = self.shape
        As, Bs, Cs = [], [], []
        D = np.zeros((p, m))
        for i in range(p):
            for j in range(m):
                A, B, C, Dij = _cascade_delay(self.entries[i][j].realisation(), self.entries[i][j].delay, order)
                As.append(A)
                Bcol = np.zeros((A.shape[0], m))
                Bcol[:, j] = B[:, 0]
                Bs.append(Bcol)
                Crow = np.zeros((p, A.shape[0]))
                Crow[i, :] = C[0, :]
                Cs.append(Crow)
                D[i, j] = Dij[0, 0]
        A = block_diag(*As)
        B = np.vstack(Bs) if Bs else np.zeros((0, m))
        C = np.hstack(Cs) if Cs else np.zeros((p, 0))
        return DelayedSS(A, B, C, D, inputs=self.inputs, outputs=self.outputs)


@dataclass(frozen=True)
class DelayedSS:
    """State space with a delay per input column and per output row.

    ``dx/dt = A x + B u_d``, ``y = C x + D u_d`` with ``u_d[j](t) = u[j](t - input_delays[j])``;
    output i is read ``output_delays[i]`` late.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    input_delays: np.ndarray = field(default_factory=lambda: np.zeros(0))
    output_delays: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        p, m = self.D.shape
        if self.input_delays.size == 0:
            object.__setattr__(self, "input_delays", np.zeros(m))
        if self.output_delays.size == 0:
            object.__setattr__(self, "output_delays", np.zeros(p))

    @property
    def shape(self) -> tuple[int, int]:
        """(p outputs, m inputs)."""
        return self.D.shape[0], self.D.shape[1]

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        """G(jw), ``(len(w), p, m)`` complex, exact delays."""
        s = 1j * np.asarray(w, dtype=float)
        n = self.A.shape[0]
        out = np.empty((s.size, *self.shape), dtype=complex)
        eye = np.eye(n)
        for k, sk in enumerate(s):
            G = self.C @ np.linalg.solve(sk * eye - self.A, self.B) + self.D if n else self.D.astype(complex)
            out[k] = np.exp(-sk * self.output_delays)[:, None] * G * np.exp(-sk * self.input_delays)[None, :]
        return out

    def dcgain(self) -> np.ndarray:
        """(p, m) static gains (raises LinAlgError for an integrating plant)."""
        n = self.A.shape[0]
        return (self.C @ np.linalg.solve(-self.A, self.B) + self.D) if n else self.D.copy()

    def pade_ss(self, order: int = 4) -> DelayedSS:
        """A delay-free realisation with every input and output delay replaced by a Padé approximant."""
        if not (np.any(self.input_delays > 0) or np.any(self.output_delays > 0)) or order <= 0:
            return self
        p, m = self.shape
        # each input channel: Padé block in front of B's column
        pre = [_cascade_delay((np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.eye(1)), d, order)
               for d in self.input_delays]
        post = [_cascade_delay((np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.eye(1)), d, order)
                for d in self.output_delays]
        Ai = block_diag(*[b[0] for b in pre])
        Bi = block_diag(*[b[1] for b in pre])
        Ci = block_diag(*[b[2] for b in pre])
        Di = np.diag([b[3][0, 0] for b in pre])
        # series: input Padé -> plant
        n, ni = self.A.shape[0], Ai.shape[0]
        A1 = np.block([[Ai, np.zeros((ni, n))], [self.B @ Ci, self.A]])
        B1 = np.vstack([Bi, self.B @ Di])
        C1 = np.hstack([self.D @ Ci, self.C])
        D1 = self.D @ Di
        Ao = block_diag(*[b[0] for b in post])
        Bo = block_diag(*[b[1] for b in post])
        Co = block_diag(*[b[2] for b in post])
        Do = np.diag([b[3][0, 0] for b in post])
        n1, no = A1.shape[0], Ao.shape[0]
        A2 = np.block([[A1, np.zeros((n1, no))], [Bo @ C1, Ao]])
        B2 = np.vstack([B1, Bo @ D1])
        C2 = np.hstack([Do @ C1, Co])
        D2 = Do @ D1
        return DelayedSS(A2, B2, C2, D2, inputs=self.inputs, outputs=self.outputs)


#: Either MIMO form; both have ``shape``, ``inputs``, ``outputs``, ``freqresp``, ``dcgain`` and ``pade_ss``.
MimoLti = TfMatrix | DelayedSS
