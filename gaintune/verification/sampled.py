"""The sampled loop: the plant as the simulator steps it, and the controllers' discrete laws.

The simulator (:mod:`gaintune.sim.kernel`) runs, at every step k (sample time dt):

1. outputs ``y[k] = C x[k] + D u[k - dD]`` with ``dD = d + 1``: the output is sampled
   before the control update, with the previous input still held (the standard
   sampled-data convention; a nonlinear plant's output map sees that input too). A
   biproper plant's feedthrough D thus reaches the controller one sample late through the
   hold, and the loop has no algebraic loop even without a delay;
2. the controllers, outer loop first, from ``y[k]`` and the setpoint at step k; the
   innermost output is ``u[k]``. There is **no** implicit sample of delay between
   measurement and actuation: ``u[k]`` is computed from ``y[k]`` and held from t_k to
   t_{k+1};
3. the plant update ``x[k+1] = Ad x[k] + G0 u[k-d] + G1 u[k-d-1]``: exact ZOH with the
   input delay ``tau = d dt + f`` (0 <= f < dt) for LTI plants (the input held over the
   sample is u[k-d-1] for the first f seconds, u[k-d] for the rest; Astrom and
   Wittenmark, *Computer-Controlled Systems*, sampling a system with a time delay), and
   one RK4 step with the input held (delay rounded to whole samples, f = 0) for
   nonlinear ones, whose linearisation is then stepped by the RK4 matrices.

So the plant seen from the controller output is, exactly,

    X(z) = (zI - Ad)^-1 (G0 + G1 z^-1) z^-d U(z),    P(z) = C X(z) + D z^-dD U(z)

and ``verify.compute_delay = c`` samples between the controller output and the plant
input add ``c`` to ``d`` and ``dD`` (``z^-c``).

The controller laws (module docstring of :mod:`gaintune.controllers.pid`) in z:

* integral ``I[k] = I[k-1] + Ki dt e[k]``: ``Ki dt / (1 - z^-1)``;
* derivative ``D[k] = Tf/(Tf+dt) D[k-1] + Kd/(Tf+dt) (ed[k] - ed[k-1])``:
  ``Kd (1 - z^-1) / (Tf + dt - Tf z^-1)`` (Tf = 0 is a plain backward difference);
* LQ: ``u = -K x[k] + Nr r + Kint Z[k]``, ``Z[k] = Z[k-1] + dt e[k]``.

Frequency responses are evaluated at z = e^{s dt}, s = j w (w up to the Nyquist
frequency pi/dt), or s = -eps + j w for the Nyquist contour |z| = e^{-eps dt}.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from gaintune.errors import SpecError
from gaintune.lti.arrays import int_power
from gaintune.plants.plant import LinearModel
from gaintune.spec import check_delay_samples

__all__ = ["SampledPlant", "sample_plant", "zoh_delay", "rk4_matrices", "discrete_ops"]


def zoh_delay(A: np.ndarray, B: np.ndarray, dt: float,
              delay: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, float]:
    """Exact ZOH with an input delay: (Ad, G0, G1, d, frac), as :func:`gaintune.sim.build.discretize`.

    ``x[k+1] = Ad x[k] + G0 u[k-d] + G1 u[k-d-1]`` with delay = d dt + frac, 0 <= frac < dt:
    ``G0 = int_0^{dt-frac} e^{A s} ds B``, ``G1 = e^{A (dt-frac)} int_0^{frac} e^{A s} ds B``.
    """
    n = A.shape[0]
    d = int(math.floor(delay / dt + 1e-9))
    frac = min(max(delay - d * dt, 0.0), dt)
    if frac < 1e-12 * dt:
        frac = 0.0

    def phi_gamma(h: float):
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = A * h
        M[:n, n:] = B * h
        import scipy.linalg  # deferred: ~0.2 s at import; `import gaintune.verification` stays light

        E = scipy.linalg.expm(M)
        return E[:n, :n], E[:n, n]

    Ad, g = phi_gamma(dt)
    if frac == 0.0:
        return Ad, g, np.zeros(n), d, 0.0
    phi_a, gam_a = phi_gamma(dt - frac)
    _, gam_b = phi_gamma(frac)
    return Ad, gam_a, phi_a @ gam_b, d, frac


def rk4_matrices(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """One classical RK4 step of dx/dt = A x + B u with u held: (Ad, G0), as the simulator steps nonlinear plants."""
    n = A.shape[0]
    M = A * dt
    eye = np.eye(n)
    M2 = M @ M
    M3 = M2 @ M
    Ad = eye + M + M2 / 2.0 + M3 / 6.0 + M3 @ M / 24.0
    G0 = (eye + M / 2.0 + M2 / 6.0 + M3 / 24.0) @ B[:, 0] * dt
    return Ad, G0


def discrete_ops(z: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """(z^-1, integral operator dt/(1 - z^-1), derivative operator Tf -> (1 - z^-1)/(Tf + dt - Tf z^-1))."""
    zi = 1.0 / z
    one_m = 1.0 - zi
    integ = dt / one_m

    def deriv(tf: np.ndarray) -> np.ndarray:
        return one_m / (tf + dt - tf * zi)

    return zi, integ, deriv


#: (T, Z, Z^H G0, Z^H G1, diag T) of the complex Schur form Ad = Z T Z^H.
_Schur = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class SampledPlant:
    """The plant as the simulator steps it, from the controller output u[k] (see the module docstring).

    ``d`` (input) and ``dD`` (feedthrough) include the computation delay.
    """

    def __init__(self, lin: LinearModel, dt: float, Ad: np.ndarray, G0: np.ndarray, G1: np.ndarray, d: int,
                 frac: float, dD: int, method: str, compute_delay: int, delay: float):
        self.lin = lin
        self.dt = float(dt)
        self.Ad, self.G0, self.G1 = Ad, G0, G1
        self.C = lin.C
        self.D = lin.D[:, 0]
        self.d, self.frac, self.dD = int(d), float(frac), int(dD)
        self.method = method
        self.compute_delay = int(compute_delay)
        self.delay = float(delay)  # the plant's own input delay (s), without the computation delay
        self.has_G1 = bool(np.any(G1 != 0.0))
        self.has_D = bool(np.any(self.D != 0.0))
        self._schur: _Schur | None = None
        self._eig: np.ndarray | None = None

    @property
    def n(self) -> int:
        """Number of plant states."""
        return self.Ad.shape[0]

    @property
    def nyquist(self) -> float:
        """The Nyquist frequency pi/dt (rad/s)."""
        return math.pi / self.dt

    @property
    def total_delay(self) -> float:
        """Input delay (s) of the sampled model: whole samples (incl. computation delay) plus the fraction."""
        return self.d * self.dt + self.frac

    @property
    def buffer_len(self) -> int:
        """Past inputs u[k-1] .. u[k-m] the closed loop needs as states."""
        m = self.d + (1 if self.has_G1 else 0)
        if self.has_D:
            m = max(m, self.dD)
        return m

    def for_model(self, lin: LinearModel) -> SampledPlant:
        """The same sampling (dt, computation delay, method, plant delay) of another model of this plant."""
        return sample_plant(lin, self.dt, self.compute_delay, self.method == "rk4", self.delay)

    def mode_factor(self, lam: np.ndarray) -> np.ndarray:
        """The per-sample factor of continuous modes lam as this plant is stepped: e^{lam dt} (ZOH) or RK4's."""
        x = np.asarray(lam) * self.dt
        if self.method == "rk4":
            return 1.0 + x + x**2 / 2.0 + x**3 / 6.0 + x**4 / 24.0
        return np.exp(x)

    def eigvals(self) -> np.ndarray:
        """Eigenvalues of Ad (computed once)."""
        if self._eig is None:
            self._eig = np.linalg.eigvals(self.Ad) if self.n else np.zeros(0, dtype=complex)
        return self._eig

    def schur(self) -> _Schur:
        """Complex Schur form Ad = Z T Z^H and Z^H G0, Z^H G1 (computed once)."""
        if self._schur is None:
            import scipy.linalg  # deferred (see above)

            T, Z = scipy.linalg.schur(self.Ad.astype(complex), output="complex")
            ZH = Z.conj().T
            self._schur = (T, Z, ZH @ self.G0.astype(complex), ZH @ self.G1.astype(complex), np.diag(T).copy())
        return self._schur

    def state_response(self, z: np.ndarray) -> np.ndarray:
        """X(z) = (zI - Ad)^-1 (G0 + G1 z^-1) z^-d per z: (W, n)."""
        z = np.asarray(z, dtype=complex)
        n = self.n
        if n == 0:
            return np.zeros((z.size, 0), dtype=complex)
        T, Z, zb0, zb1, diag = self.schur()
        zi = 1.0 / z
        x = np.empty((n, z.size), dtype=complex)
        with np.errstate(all="ignore"):
            for i in range(n - 1, -1, -1):
                acc = zb0[i] + zb1[i] * zi if self.has_G1 else np.full(z.size, zb0[i])
                if i + 1 < n:
                    acc = acc + T[i, i + 1 :] @ x[i + 1 :]
                x[i] = acc / (z - diag[i])
            x = x * int_power(zi, self.d) if self.d else x  # NumPy's ** is ~30x slower from d = 100
        return (Z @ x).T

    def responses(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(X (W, n), P (W, q)): u -> x and u -> y of the sampled plant."""
        X = self.state_response(z)
        P = X @ self.C.T
        if self.has_D:
            P = P + self.D[None, :] * int_power(1.0 / np.asarray(z, dtype=complex)[:, None], self.dD)
        return X, P


_CACHE: dict[tuple, tuple[LinearModel, SampledPlant]] = {}


def _check_finite(sp: SampledPlant, A: np.ndarray) -> None:
    """Raise SpecError when the sampled plant overflowed (plant time scales absurd for dt, or dt
    for the plant): no figure of such a loop could be trusted."""
    if all(np.all(np.isfinite(M)) for M in (sp.Ad, sp.G0, sp.G1, sp.C, sp.D)):
        return
    with np.errstate(all="ignore"):
        a = float(np.max(np.abs(A))) if A.size else 1.0
    # blame whichever of the plant's rate |A| and dt is further from ordinary scales
    plant_side = not math.isfinite(a) or abs(math.log10(max(a, 1e-320))) >= abs(math.log10(sp.dt))
    field = "plant" if plant_side else "scenario.dt"
    raise SpecError(field, f"the plant sampled at dt = {sp.dt:.3g} s (the largest scenario dt) is not finite "
                           f"(plant matrix entries up to {a:.3g}): plant coefficients or dt out of any usable range")


def sample_plant(lin: LinearModel, dt: float, compute_delay: int = 0, nonlinear: bool = False,
                 delay: float | None = None) -> SampledPlant:
    """The sampled plant of ``lin`` at ``dt`` (memoised per model object, dt, delays and method).

    ``delay``: the plant's input delay in seconds (default ``lin.delay``; robust samples draw it).
    ``nonlinear``: step the linearisation as the simulator steps nonlinear plants (RK4, delay
    rounded to whole samples, output map seeing the previous held input).
    """
    delay = float(lin.delay if delay is None else delay)
    key = (id(lin), float(dt), int(compute_delay), bool(nonlinear), delay)
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is lin:
        return hit[1]
    check_delay_samples(delay, dt)
    A, B = lin.A, lin.B
    c = int(compute_delay)
    if nonlinear:
        Ad, G0 = rk4_matrices(A, B, dt) if A.size else (np.zeros((0, 0)), np.zeros(0))
        d = int(round(delay / dt))
        sp = SampledPlant(lin, dt, Ad, G0, np.zeros_like(G0), d + c, 0.0, d + c + 1, "rk4", c, delay)
    else:
        if A.size:
            Ad, G0, G1, d, frac = zoh_delay(A, B, dt, delay)
        else:
            d = int(math.floor(delay / dt + 1e-9))
            Ad, G0, G1, frac = np.zeros((0, 0)), np.zeros(0), np.zeros(0), 0.0
        sp = SampledPlant(lin, dt, Ad, G0, G1, d + c, frac, d + c + 1, "zoh", c, delay)
    _check_finite(sp, A)
    if len(_CACHE) > 512:
        _CACHE.clear()
    _CACHE[key] = (lin, sp)
    return sp
