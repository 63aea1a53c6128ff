"""Closed-loop stability of the whole MIMO loop: Padé eigenvalues and the generalised Nyquist count.

Two independent methods (negative feedback ``u = K (r - y)``, :mod:`.mimo_loop`):

* **Eigenvalues** of the closed-loop state matrix built from minimal realisations of the plant's
  loop channels (every delay replaced by its Padé approximant) and of the controller.
* **Generalised Nyquist count** on the exact delays: along s = -eps + jw, with
  chi_cl(s) = chi_ol(s) det(I + L(s)), the closed-loop roots right of the contour are
  Z = P - (change of arg det(I + L) for w from 0 to inf) / pi, P the open-loop poles right of it
  (plant and controller, delay-free); conjugate symmetry gives the lower half. L is taken on the
  smaller side (det(I + Ks Gs) = det(I + Gs Ks)), of size n. The contour runs up
  to where sigma_max(L) < sin(pi / 2n) / 2, so that each eigenvalue of I + L stays within a small
  angle of 1 and the principal angle closes the tail (checked on the grid and one far point).

With delays the Nyquist count decides (it is exact); without, the eigenvalues do. Both are
reported, with whether they agree. Plant modes the loop channels do not see (hidden modes) are
not moved by feedback: an unstable one fails the loop, a marginal one is noted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gaintune.verification.mimo_loop import MimoLoop, char_freqs, closed_loop_matrix
from gaintune.verification.mimo_plant import plant_eigvals, plant_memo
from gaintune.verification.mimo_products import block_eigvals

__all__ = ["MimoStability", "mimo_stability", "minimal_part", "hidden_modes_in_full", "trim_hidden", "contour_shift",
           "independent_parts", "trim_hidden_by_parts"]

#: Points around every open-loop pole, in units of its distance to the contour (as the SISO count).
_POLE_OFFSETS = np.concatenate([-(2.0 ** np.arange(9, -4, -1)), [0.0], 2.0 ** np.arange(-3, 10)])


@dataclass
class MimoStability:
    """Closed-loop stability of the MIMO loop: the verdict, both counts and the poles."""

    stable: bool
    method: str  # "nyquist" (exact delays decide) | "poles" | "growth" (a search check's screen) | "unchecked"
    rhp_poles: int  # closed-loop eigenvalues with Re >= 0 (Padé), hidden unstable modes included
    nyquist_rhp: int | None  # generalised Nyquist count (exact delays); None when not computable
    agree: bool
    poles: np.ndarray
    pade_order: int
    max_real_pole: float
    hidden_modes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=complex))
    notes: list[str] = field(default_factory=list)


def _det_contour(loop: MimoLoop, ol: np.ndarray, eps: float, w_hi: float, T_spin: float,
                 n_freq: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """det(I + L) along s = -eps + jw, 0 <= w <= w_hi, refined until its phase steps stay below 0.3 rad."""
    eye = np.eye(loop.n_small)

    def det(w: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            return np.linalg.det(eye + _l_small(loop, -eps + 1j * w))

    up = ol[ol.imag > 0]
    dist = np.maximum(np.abs(up.real + eps), eps)
    w = np.concatenate([[0.0], np.logspace(np.log10(eps / 100), np.log10(w_hi), n_freq),
                        (up.imag[:, None] + dist[:, None] * _POLE_OFFSETS[None, :]).ravel()])
    w = np.unique(w[(w >= 0) & (w <= w_hi)])
    if T_spin > 0:  # the delays turn the phase by about T dw per interval, where det(I + L) is not near 1
        with np.errstate(all="ignore"):
            far = np.abs(det(w) - 1.0) > 0.1
        w_top = float(w[np.nonzero(far)[0][-1]]) if far.any() else 0.0
        w = np.unique(np.concatenate([w, np.linspace(0.0, w_top, min(int(w_top * T_spin / 0.5) + 2, 20000))]))
    phi = det(w)
    for _ in range(10):
        with np.errstate(all="ignore"):
            bad = np.nonzero(np.abs(np.angle(phi[1:] / phi[:-1])) > 0.3)[0][:4000]
        if bad.size == 0:
            break
        new = (w[bad, None] + (w[bad + 1] - w[bad])[:, None] * np.linspace(0, 1, 10)[None, 1:-1]).ravel()
        wn = np.concatenate([w, new])
        o = np.argsort(wn, kind="stable")
        w, phi = wn[o], np.concatenate([phi, det(new)])[o]
    return w, phi


def _sigma_l(loop: MimoLoop, w: np.ndarray, eps: float) -> np.ndarray:
    """An upper bound of sigma_max(L) (its Frobenius norm) at s = -eps + jw."""
    with np.errstate(all="ignore"):
        return np.linalg.norm(_l_small(loop, -eps + 1j * np.asarray(w, dtype=float)), axis=(1, 2))


def _nyquist(loop: MimoLoop, ol: np.ndarray, eps: float, cf: np.ndarray, notes: list[str]) -> int | None:
    """Closed-loop roots right of Re s = -eps by the generalised Nyquist criterion (exact delays)."""
    tau = 0.5 * math.sin(math.pi / (2 * loop.n_small))
    w_hi = 100.0 * float(cf.max())
    for _ in range(8):
        if _sigma_l(loop, np.array([w_hi]), eps)[0] < tau:
            break
        w_hi *= 10.0
    tail_ok = bool(np.all(_sigma_l(loop, w_hi * np.array([10.0, 1e2, 1e4]), eps) < tau))
    w, phi = _det_contour(loop, ol, eps, w_hi, 2.0 * loop.max_delay())
    with np.errstate(all="ignore"):
        far = complex(np.linalg.det(np.eye(loop.n_small) + _l_small(loop, np.array([-eps + 1j * w_hi * 1e4]))[0]))
    ang = np.unwrap(np.angle(phi))
    turn = ang[-1] - ang[0] + float(np.angle(far / phi[-1]))
    P = int(np.sum(ol.real > -eps))
    z_real = P - turn / math.pi
    if not math.isfinite(z_real):
        notes.append("generalised Nyquist count not computable (the loop response overflows)")
        return None
    z = int(round(z_real))
    if abs(z_real - z) > 0.25:
        notes.append("generalised Nyquist count is not close to an integer; the contour may be too coarse")
    if not tail_ok:
        notes.append(f"sigma_max(L) does not fall below {tau:.3g} at high frequency: the Nyquist tail is not "
                     "verified (a loop with direct feedthrough and delay may be neutral)")
        z = max(z, 1) if loop.max_delay() > 0 else z
    return z


def _l_small(loop: MimoLoop, s: np.ndarray) -> np.ndarray:
    """The loop gain on the smaller side (Ks Gs at the inputs or Gs Ks at the outputs) at ``s``."""
    return loop.loop_gains(s, "input" if loop.n_in <= loop.n_out else "output")


def _drop(values: np.ndarray, remove: np.ndarray) -> np.ndarray:
    """``values`` without the entry nearest to each of ``remove`` (one entry each)."""
    keep = np.ones(values.size, dtype=bool)
    for r in remove:
        if not keep.any():
            break
        d = np.where(keep, np.abs(values - r), np.inf)
        keep[int(np.argmin(d))] = False
    return values[keep]


def hidden_notes(bad: np.ndarray, marginal: np.ndarray, notes: list[str], kind: str = "") -> None:
    """Say which ``kind`` (e.g. ``sampled ``) plant modes the loop channels cannot see: unstable ones fail the
    loop, marginal ones are left out of the verdict."""
    if bad.size:
        notes.append(f"unstable {kind}plant mode(s) {np.round(bad, 6).tolist()} not seen by the loop channels: "
                     "feedback cannot stabilise them")
    if marginal.size:
        notes.append(f"marginal {kind}plant mode(s) {np.round(marginal, 6).tolist()} not seen by the loop "
                     "channels: left out of the verdict")


def _split_hidden(hidden: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unstable, marginal) hidden plant modes (a hidden chain on the axis is spread by rounding)."""
    sc = max(1.0, float(np.max(np.abs(hidden)))) if hidden.size else 1.0
    return hidden[hidden.real > 1e-6 * sc], hidden[np.abs(hidden.real) <= 1e-6 * sc]


def minimal_part(A: np.ndarray, B: np.ndarray, C: np.ndarray,
                 rtol: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A minimal realisation (A2, B2, C2) of (A, B, C): the Ho-Kalman realisation of its block Hankel
    matrix of Markov parameters ``C (A/a)^k B`` (a = max(1, ||A||); its rank, singular values above
    ``rtol`` times the largest, is the minimal order).

    The Markov parameters do not depend on the state coordinates, so a badly scaled realisation
    (a cascade's controller realised entry by entry has B near 1e-7 and C near 1e23) still gives a
    clean rank, where a Kalman staircase on the states misjudges it; and every hidden Jordan chain
    (a cascade repeats its integrators in several entries) is counted in full."""
    n, p, m = A.shape[0], C.shape[0], B.shape[1]
    if n == 0 or p == 0 or m == 0:
        return np.zeros((0, 0)), np.zeros((0, m)), np.zeros((p, 0))
    a = max(1.0, float(np.linalg.norm(A, 2)))
    As = A / a
    rows = n - int(np.linalg.matrix_rank(C)) + 1  # bounds of the observability and controllability indices
    cols = n - int(np.linalg.matrix_rank(B)) + 1
    M, X = [C @ B], B
    for _ in range(rows + cols - 1):
        X = As @ X
        M.append(C @ X)
    H0 = np.block([[M[i + j] for j in range(cols)] for i in range(rows)])
    H1 = np.block([[M[i + j + 1] for j in range(cols)] for i in range(rows)])
    U, sv, Vh = np.linalg.svd(H0, full_matrices=False)
    r = int(np.sum(sv > rtol * sv[0])) if sv.size and sv[0] > 0 else 0
    if r == 0:
        return np.zeros((0, 0)), np.zeros((0, m)), np.zeros((p, 0))
    h = np.sqrt(sv[:r])
    A2 = (U[:, :r].T @ H1 @ Vh[:r].T) / h[:, None] / h[None, :] * a
    return A2, (h[:, None] * Vh[:r])[:, :m], (U[:, :r] * h[None, :])[:p]


def _split(A: np.ndarray, B: np.ndarray, C: np.ndarray, discrete: bool, thr: float) -> tuple[int, tuple, tuple]:
    """(k, right part (A_r, B_r, C_r), left part (A_l, B_l, C_l)): the additive split of (A, B, C)
    into the k eigenvalues whose :func:`_criterion` exceeds ``thr`` and the others, by the ordered real
    Schur form block-diagonalised with a Sylvester solve. Only the (few) modes that matter to a
    stability count go through :func:`minimal_part`. When no ordered Schur form can be had (see
    :func:`_ordered_schur`), k = 0: nothing is trimmed, so every mode stays counted (the cautious side)."""
    import scipy.linalg

    try:
        T, Q, Qi, k = _ordered_schur(A, discrete, thr)
    except np.linalg.LinAlgError:
        return 0, (A[:0, :0], B[:0], C[:, :0]), (A, B, C)
    ZB, CZ = Qi @ B, C @ Q
    if k in (0, A.shape[0]):
        return k, (T[:k, :k], ZB[:k], CZ[:, :k]), (T[k:, k:], ZB[k:], CZ[:, k:])
    X = scipy.linalg.solve_sylvester(T[:k, :k], -T[k:, k:], -T[:k, k:])
    return k, (T[:k, :k], ZB[:k] - X @ ZB[k:], CZ[:, :k]), (T[k:, k:], ZB[k:], CZ[:, :k] @ X + CZ[:, k:])


def _criterion(re: np.ndarray, im: np.ndarray, discrete: bool) -> np.ndarray:
    """What the split compares with its threshold: Re s, or (``discrete``) |z|^2."""
    return re * re + im * im if discrete else re


def _ordered_schur(A: np.ndarray, discrete: bool, thr: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(T, Q, Q^-1, k): A = Q T Q^-1 with T real Schur, the k eigenvalues above ``thr`` first.

    LAPACK refuses the reordering when an eigenvalue within rounding of the threshold moves across it
    as the form is reordered ("leading eigenvalues do not satisfy sort condition"); the threshold then
    moves into the nearby gaps between the eigenvalues' criteria, where no rounding reaches, and, for
    a badly scaled A (a cascade's controller realised entry by entry), the same is tried on A balanced
    (``scipy.linalg.matrix_balance``: Q = D Z). LinAlgError when nothing works."""
    import scipy.linalg

    if not np.all(np.isfinite(A)):
        raise np.linalg.LinAlgError("a non-finite matrix has no Schur form")
    Ab, (sc, _) = scipy.linalg.matrix_balance(A, permute=False, separate=True)
    for M, d in ((A, None), (Ab, sc)):
        for t in _thresholds(M, discrete, thr):
            def above(re: np.ndarray, im: np.ndarray, t: float = t) -> np.ndarray:
                return _criterion(re, im, discrete) > t

            try:
                T, Z, k = scipy.linalg.schur(M, output="real", sort=above)
            except (np.linalg.LinAlgError, ValueError):
                continue
            if d is None:
                return T, Z, Z.T, k
            return T, d[:, None] * Z, Z.T / d[None, :], k
    raise np.linalg.LinAlgError("no threshold separates the eigenvalues for an ordered Schur form")


def _thresholds(A: np.ndarray, discrete: bool, thr: float) -> list[float]:
    """``thr``, then the midpoint of the gap between the eigenvalues' criteria that holds ``thr`` (every
    eigenvalue keeps its side), then the midpoints of the gaps next to it, nearest first."""
    ev = np.linalg.eigvals(A)
    v = np.unique(_criterion(ev.real, ev.imag, discrete))
    i = int(np.searchsorted(v, thr, side="right"))  # v[:i] <= thr < v[i:]
    order = sorted(range(v.size - 1), key=lambda j: (abs(j - (i - 1)), j))
    return [thr] + [0.5 * (v[j] + v[j + 1]) for j in order[:4]]


def _threshold(A: np.ndarray, floor: float, discrete: bool) -> float:
    """The split's threshold: Re s > ``floor`` |lambda|max, or (``discrete``) |z| > 1 - 1e-6."""
    if discrete:
        return (1.0 - 1e-6) ** 2
    ev = np.linalg.eigvals(A)
    return floor * max(1.0, float(np.max(np.abs(ev))))


def trim_hidden(A: np.ndarray, B: np.ndarray, C: np.ndarray, floor: float = -1e-6,
                discrete: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A', B', C', hidden): a realisation of the same system without the modes right of Re s =
    ``floor`` |lambda|max (``discrete``: |z| > 1 - 1e-6) that B and C cannot reach or see, and those
    modes, each counted with its full multiplicity (:func:`minimal_part` of that part). Stable modes
    are kept as they are."""
    if not A.size:
        return A, B, C, np.zeros(0, dtype=complex)
    return _trimmed(A, B, C, discrete, _threshold(A, floor, discrete))


def _trimmed(A: np.ndarray, B: np.ndarray, C: np.ndarray, discrete: bool,
             thr: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`trim_hidden` at the split threshold ``thr``."""
    k, (Ar, Br, Cr), (Al, Bl, Cl) = _split(A, B, C, discrete, thr)
    if k == 0:
        return A, B, C, np.zeros(0, dtype=complex)
    A2, B2, C2 = minimal_part(Ar, Br, Cr)
    right = np.linalg.eigvals(Ar)
    hidden = _drop(right, np.linalg.eigvals(A2)) if A2.size else right
    n2 = A2.shape[0]
    At = np.zeros((n2 + Al.shape[0],) * 2)
    At[:n2, :n2], At[n2:, n2:] = A2, Al
    return At, np.vstack([B2, Bl]), np.hstack([C2, Cl]), hidden


#: Above this estimate of the SVD work of the whole Hankel matrix, :func:`trim_hidden_by_parts` splits.
_HANKEL_FLOPS = 1e9


def _hankel_flops(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> float:
    """The SVD work of :func:`minimal_part`'s Hankel matrix of the whole (A, B, C), at most (all its states)."""
    n = A.shape[0]
    r = (n - int(np.linalg.matrix_rank(C)) + 1) * C.shape[0]
    c = (n - int(np.linalg.matrix_rank(B)) + 1) * B.shape[1]
    return float(min(r, c)) ** 2 * max(r, c)


def independent_parts(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(states, inputs, outputs) of the independent parts of (A, B, C): connected through A, or through an
    input or an output two states share. Each part is a system of its own (a decentralised or cascaded
    controller: one per chain), so a minimal realisation of the whole is one of each part, side by side."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    G = np.zeros((n + m + p,) * 2, dtype=bool)
    G[:n, :n] = A != 0
    G[:n, n : n + m] = B != 0
    G[n + m :, :n] = C != 0
    _, label = connected_components(csr_matrix(G), directed=False)
    out = []
    for lab in np.unique(label[:n]):
        out.append((np.flatnonzero(label[:n] == lab), np.flatnonzero(label[n : n + m] == lab),
                    np.flatnonzero(label[n + m :] == lab)))
    return out


def trim_hidden_by_parts(A: np.ndarray, B: np.ndarray, C: np.ndarray,
                         floor: float = -1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A', B', C') of :func:`trim_hidden` (continuous, the threshold of the whole A) taken part by part
    (:func:`independent_parts`): the same transfer matrix and the same kept modes, each part's minimal
    realisation from its own small Hankel matrix (the whole's, for 22 cascades, is ~1000 x 1000), when the
    whole's would cost more than ``_HANKEL_FLOPS``. The realisations differ by rounding: the closed-loop
    poles agree to their conditioning (the process train's largest |z| to ~1e-12)."""
    parts = independent_parts(A, B, C) if A.size and _hankel_flops(A, B, C) > _HANKEL_FLOPS else []
    if len(parts) < 2:  # small enough: the whole, as trim_hidden (to the last bit)
        return trim_hidden(A, B, C, floor)[:3]
    thr = _threshold(A, floor, False)
    As, Bs, Cs = [], [], []
    for st, ins, outs in parts:
        a, b, c, _ = _trimmed(A[np.ix_(st, st)], B[np.ix_(st, ins)], C[np.ix_(outs, st)], False, thr)
        Bp, Cp = np.zeros((a.shape[0], B.shape[1])), np.zeros((C.shape[0], a.shape[0]))
        Bp[:, ins], Cp[outs] = b, c
        As.append(a)
        Bs.append(Bp)
        Cs.append(Cp)
    n2 = sum(a.shape[0] for a in As)
    At = np.zeros((n2, n2))
    k = 0
    for a in As:
        At[k : k + a.shape[0], k : k + a.shape[0]] = a
        k += a.shape[0]
    return At, np.vstack(Bs), np.hstack(Cs)


def hidden_modes_in_full(A: np.ndarray, B: np.ndarray, C: np.ndarray, floor: float) -> np.ndarray:
    """The eigenvalues of A right of Re s = ``floor`` |lambda|max that are not poles of the minimal
    realisation: modes feedback through B and C cannot move, each counted with its full
    multiplicity (:func:`trim_hidden`)."""
    return trim_hidden(A, B, C, floor)[3]


def _hidden(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """:func:`hidden_modes_in_full` at the stability count's floor, remembered for a kept plant realisation."""
    return plant_memo(A, B, C, "hidden", lambda: hidden_modes_in_full(A, B, C, -1e-6))


def _open_loop_poles(loop: MimoLoop) -> np.ndarray:
    """Delay-free open-loop poles of plant channels and controller that feedback can move (hidden ones
    are counted apart), for the Nyquist count."""
    P, Kc = loop.realisations(0)
    parts = []
    for A, B, C, _ in (P, Kc):
        if A.size:
            parts.append(_drop(plant_eigvals(A), _hidden(A, B, C)))
    return np.concatenate(parts) if parts else np.zeros(0, dtype=complex)


def contour_shift(ol: np.ndarray, eps0: float) -> float:
    """How far left of the imaginary axis the Nyquist contour runs, at least ``eps0``.

    Poles at the origin come out of an eigenvalue solver spread by rounding: a chain of k of them
    by about (1e-16 ||A||)^(1/k), e.g. +-1e-8 for a double integrator in general coordinates, some
    left of a contour at a tiny shift, so the open-loop count P and the contour disagreed and the
    count came out wrong (negative, or "unstable"). The shift starts at 3 times the size of the
    cluster of poles at the origin (the smallest poles, each within 100 times the one before it, none
    beyond 10 (1e-16 S)^(1/3), S = max(1, max |pole|)): every spread
    pole is then right of the contour, as the true poles on the axis are. It then rises by decades
    until no pole's real part is within a factor 3 of it, so every other pole is classified the same
    way in P and by the contour."""
    ol = np.asarray(ol)
    mag = np.sort(np.abs(ol))
    bound = 10.0 * (1e-16 * max(1.0, float(mag[-1]) if mag.size else 1.0)) ** (1.0 / 3.0)
    spread, prev = 0.0, math.inf
    for m in mag:
        if m > bound or m > 100.0 * prev:
            break
        spread, prev = float(m), max(float(m), eps0)
    eps = max(eps0, 3.0 * spread)
    re = -ol.real
    for _ in range(9):
        if not np.any((re > eps / 3.0) & (re < 3.0 * eps)):
            return eps
        eps *= 10.0
    return eps


def mimo_stability(loop: MimoLoop, pade_order: int | None = None) -> MimoStability:
    """Closed-loop stability of ``loop``: Padé eigenvalues (order ``pade_order``, default 6 with
    delays) and the generalised Nyquist count on the exact delays (see the module docstring)."""
    notes: list[str] = []
    T = loop.max_delay()
    order = (6 if pade_order is None else int(pade_order)) if T > 0 else 0
    P, Kc = loop.realisations(order)
    A = closed_loop_matrix(P, Kc)
    with np.errstate(all="ignore"):
        poles = block_eigvals(A) if A.size and np.all(np.isfinite(A)) else np.zeros(0, dtype=complex)
    hid_p = _hidden(P[0], P[1], P[2])  # plant-only: computed once per plant
    # artefacts of the controller's realisation (a cascade's, entry by entry, repeats its integrators)
    hid_k = _hidden(Kc[0], Kc[1], Kc[2])
    poles = _drop(poles, np.concatenate([hid_p, hid_k]))
    bad, marginal = _split_hidden(hid_p)
    hidden_notes(bad, marginal, notes)
    scale = max(1.0, float(np.max(np.abs(poles))) if poles.size else 1.0)
    rhp = int(np.sum(poles.real > -1e-12 * scale)) + int(bad.size)
    cf = char_freqs(loop)
    ol = _open_loop_poles(loop)
    nyq = _nyquist(loop, ol, contour_shift(ol, 1e-7 * float(cf.min())), cf, notes)
    if nyq is not None:
        nyq += int(bad.size)
    agree = nyq == rhp
    method, n_rhp = ("nyquist", nyq) if T > 0 and nyq is not None else ("poles", rhp)
    if not agree:
        notes.append(f"generalised Nyquist count ({nyq}) differs from the Padé pole count ({rhp}); "
                     f"{'the Nyquist count (exact delays)' if method == 'nyquist' else 'the poles'} decide")
    max_re = float(np.max(poles.real)) if poles.size else -math.inf
    poles = poles[np.argsort(-poles.real, kind="stable")]
    return MimoStability(n_rhp == 0, method, rhp, nyq, agree, poles, order, max_re,
                         np.concatenate([bad, marginal]), notes)
