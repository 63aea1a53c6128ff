"""The search's sampled MIMO check at 110 gains (issue 28): the fast path (the plant's channels as first-order
terms by independent state blocks, sparse loop gains, a cascade's output breaks on the input side, the
controller trimmed chain by chain) gives the figures of the dense computation it replaced."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from gaintune.evaluation.evaluator import Evaluator
from gaintune.lti.mimo import TfEntry, TfMatrix
from gaintune.spec import load_spec
from gaintune.verification import mimo_sampled_report as msr
from gaintune.verification import mimo_stability
from gaintune.verification.mimo_loop import LoopPair, MimoLoop, PidLoop, decentralised_pid
from gaintune.verification.mimo_sampled import SampledCore, SampledLoop, sampled_core
from gaintune.verification.mimo_sampled_report import sampled_margins, sampled_report
from gaintune.verification.mimo_stability import trim_hidden, trim_hidden_by_parts


def _close(a: Any, b: Any, rtol: float, where: str = "report") -> None:
    """Assert a == b through dataclasses and lists, numbers to ``rtol`` (NaN equal to NaN); pole lists by
    count only (the poles of a long delay chain at z ~ 0 are rounding noise in any realisation)."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            if f.name == "poles":
                assert np.size(getattr(a, f.name)) == np.size(getattr(b, f.name)), where
            else:
                _close(getattr(a, f.name), getattr(b, f.name), rtol, f"{where}.{f.name}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, rtol, f"{where}[{k}]")
    elif isinstance(a, float | complex | np.ndarray) and not isinstance(a, bool):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=rtol, atol=0.0, equal_nan=True, err_msg=where)
    else:
        assert a == b, where


def _entry(num, den, delay: float = 0.0) -> TfEntry:
    return TfEntry(np.array(num, float), np.array(den, float), delay)


def _random_2x2(seed: int) -> TfMatrix:
    """A random 2 x 2 plant: lags with fractional delays, and one repeated pole (a defective block)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(2):
        row = []
        for j in range(2):
            tau, k, delay = rng.uniform(0.5, 5.0), rng.uniform(-2.0, 2.0), rng.uniform(0.0, 1.3)
            den = np.polymul([tau, 1.0], [tau, 1.0]) if (i, j) == (1, 1) else [tau, 1.0]
            row.append(_entry([k], den, delay))
        rows.append(tuple(row))
    return TfMatrix(tuple(rows), inputs=("u1", "u2"), outputs=("y1", "y2"))


def _solve_reference(core: SampledCore, z: np.ndarray, n_in: int) -> np.ndarray:
    """Gs(z) point by point: C (zI - Ad)^-1 sum_c (G0 + G1 z^-1) z^-d(c) into the channel's input."""
    out = np.zeros((z.size, core.C.shape[0], n_in), dtype=complex)
    for k, zk in enumerate(z):
        B = np.zeros((core.Ad.shape[0], n_in), dtype=complex)
        for c, (j, d) in enumerate(zip(core.src, core.d, strict=True)):
            B[:, j] += (core.G0[:, c] + core.G1[:, c] / zk) * zk ** (-float(d))
        out[k] = core.C @ np.linalg.solve(zk * np.eye(core.Ad.shape[0]) - core.Ad, B)
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sampled_terms_equal_the_dense_and_the_solved_response_on_a_random_2x2(seed: int) -> None:
    """The first-order terms (a repeated pole's block solved per point) give the dense modal response and a
    solve per point, to rounding."""
    core = sampled_core(_random_2x2(seed), [0, 1], [0, 1], 0.4, np.zeros(2))
    terms = core.terms(2)
    assert len(terms.solved) == 1 and np.any(core.G1)  # the repeated pole; fractional delays
    z = np.exp(1j * np.linspace(1e-3, np.pi, 400))
    fast = np.zeros((z.size, 2, 2), dtype=complex)
    fast[:, terms.rows, terms.cols] = terms.values(z)
    ref = _solve_reference(core, z, 2)
    scale = np.abs(ref).max()
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-11 * scale)
    np.testing.assert_allclose(core.response_dense(z, 2), ref, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(core.response(z, 2), ref, rtol=0, atol=1e-9 * scale)  # whichever it takes


@pytest.mark.parametrize("seed", [0, 1])
def test_sparse_sampled_loop_figures_equal_the_dense_ones_on_a_random_2x2(seed: int, monkeypatch) -> None:
    """The sampled loop's report from the sparse loop gains equals the dense one's (loop-at-a-time margins,
    Ms, Mt, disk margins) to 1e-9."""
    plant = _random_2x2(seed)
    pid = [PidLoop("l1", "y1", "u1", Kp=0.3 * np.sign(plant.entries[0][0].num[0]), Ki=0.05 * np.sign(
        plant.entries[0][0].num[0])), PidLoop("l2", "y2", "u2", Kp=0.2 * np.sign(plant.entries[1][1].num[0]),
                                               Ki=0.03 * np.sign(plant.entries[1][1].num[0]))]
    pairs = [LoopPair(p.name, p.output, p.input) for p in pid]
    base = MimoLoop.build(plant, decentralised_pid(plant, pid), pairs)

    def report(sparse: bool) -> Any:
        monkeypatch.setattr(SampledCore, "sparse", lambda self, n_in: sparse)
        core = sampled_core(plant, base.ins, base.outs, 0.4, np.zeros(2))
        return sampled_report(base, SampledLoop.of(base, core))

    fast, dense = report(True), report(False)
    assert dense.input_breaks and dense.stability.stable == fast.stability.stable
    _close(fast, dense, 1e-9)


def _train_spec(units: int = 3) -> dict:
    """A small process train (the model process_train's form): unit k's valve u_k drives its flow F_k and
    its temperature T_k, and its neighbours' temperatures with twice the delay; T_k PID -> F_k PI."""
    rows, loops = [], []
    for k in range(units):
        tau, theta = 60.0 + 40.0 * (k % 4), 8.0 + 4.0 * (k % 3)
        lag = np.polymul([4.0, 1.0], [tau, 1.0]).tolist()
        f_row: list = [0] * (units + 1)
        f_row[k] = {"num": [0.02], "den": [4.0, 1.0]}
        t_row: list = [0] * (units + 1)
        t_row[k] = {"num": [0.5], "den": lag, "delay": theta}
        for j in (k - 1, k + 1):
            if 0 <= j < units:
                t_row[j] = {"num": [-0.05], "den": lag, "delay": 2 * theta}
        t_row[units] = {"num": [0.8], "den": np.polymul([30.0, 1.0], [tau, 1.0]).tolist(), "delay": theta}
        rows += [f_row, t_row]
        loops += [{"name": f"T{k + 1}", "measure": f"T{k + 1}", "drives": f"loop:F{k + 1}", "type": "pid",
                   "direction": "direct",
                   "gains": {g: {"value": v} for g, v in (("Kp", 0.15), ("Ki", 0.0015), ("Kd", 0.01))}},
                  {"name": f"F{k + 1}", "measure": f"F{k + 1}", "drives": f"u{k + 1}", "type": "pi",
                   "direction": "direct", "gains": {"Kp": {"value": 50.0}, "Ki": {"value": 25.0}}}]
    ins = [{"name": f"u{k + 1}"} for k in range(units)] + [{"name": "Tf"}]
    outs = [{"name": f"{v}{k + 1}"} for k in range(units) for v in ("F", "T")]
    return {"name": "train", "plant": {"tf_matrix": {"inputs": ins, "outputs": outs, "entries": rows}},
            "loops": loops, "scenarios": [{"name": "feed", "dt": 1.0, "horizon": 100.0, "reference": {"kind": "none"},
                                           "disturbance": {"kind": "step", "amplitude": 5.0, "time": 10.0,
                                                           "input": "Tf"}}]}


def test_process_train_check_takes_the_fast_path_with_the_dense_figures(monkeypatch) -> None:
    """Regression (issue 28): the 110-gain train's sampled check evaluated every channel through the whole
    plant's modes (~1 s a candidate). On a 3-unit train (a cascade: 6 loops on 3 inputs) the fast path's
    report equals the dense path's (the computation it replaced), the aimed and the full one, to 1e-9;
    the controller, small here, is trimmed whole in both."""
    spec = load_spec(_train_spec())
    ev = Evaluator(spec)
    rng = np.random.default_rng(5)
    base = ev.layout.initial_tuned()  # the spec's given gains
    for row in base[None] * np.exp(rng.normal(0.0, 0.3, (3, base.size))):
        full = ev.layout.full(row[None])[0]
        msr._CORES.clear()
        sl, fast, lines = sampled_margins(ev.spec, ev.plant, ev.layout, full)
        _, loop = msr.sampled_loop(ev.spec, ev.plant, sl)
        assert loop.core is not None and loop.core.sparse(loop.n_in) and loop.outputs_by_inputs()
        _, fast_aim, _ = sampled_margins(ev.spec, ev.plant, ev.layout, full, aimed=True)
        with monkeypatch.context() as m:
            m.setattr(SampledCore, "sparse", lambda self, n_in: False)
            _, dense, dense_lines = sampled_margins(ev.spec, ev.plant, ev.layout, full)
            _, dense_aim, _ = sampled_margins(ev.spec, ev.plant, ev.layout, full, aimed=True)
        assert dense.output_breaks and len(dense.output_breaks) == 6
        _close(fast, dense, 1e-9)
        _close(fast_aim, dense_aim, 1e-9)
        _close(lines, dense_lines, 1e-9, "lines")  # the same requirement lines, passed or not


def test_controller_trimmed_chain_by_chain_keeps_its_transfer_matrix_and_its_poles(monkeypatch) -> None:
    """Trimming a many-cascade controller part by part (each chain's repeated integrators) leaves the
    realisation the whole trim leaves: the same order, transfer matrix and poles (to rounding)."""
    spec = load_spec(_train_spec(4))
    ev = Evaluator(spec)
    sl = msr.spec_loop(ev.spec, ev.plant, ev.layout, ev.layout.full(ev.layout.initial_tuned()[None])[0])
    base = MimoLoop.build(sl.plant, sl.controller, sl.pairing)
    A, B, C, _ = base.realisations(0)[1]
    assert len(mimo_stability.independent_parts(A, B, C)) == 4
    whole = trim_hidden(A, B, C)[:3]
    for got, want in zip(trim_hidden_by_parts(A, B, C), whole, strict=True):  # small: trimmed whole, bit for bit
        np.testing.assert_array_equal(got, want)
    monkeypatch.setattr(mimo_stability, "_HANKEL_FLOPS", 0.0)
    parts = trim_hidden_by_parts(A, B, C)
    assert parts[0].shape == whole[0].shape and parts[0].shape[0] < A.shape[0]
    s = 1j * np.logspace(-3, 1, 7)

    def tf(r: tuple) -> np.ndarray:
        Ar, Br, Cr = r
        return np.array([Cr @ np.linalg.solve(x * np.eye(Ar.shape[0]) - Ar, Br) for x in s])

    want = tf(whole)  # (the whole trim leaves ~1e-16 relative between the chains; the parts none)
    np.testing.assert_allclose(tf(parts), want, rtol=1e-9, atol=1e-14 * np.abs(want).max())
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(parts[0])),
                               np.sort_complex(np.linalg.eigvals(whole[0])), atol=1e-9)


def test_divergence_rate_reads_the_spectral_radius_of_a_clearly_unstable_loop_only() -> None:
    """The screen's figure is the growth per step: the spectral radius where x grows 10,000-fold over the
    second half of its steps; None for a stable matrix, a slowly unstable one (left to the eigenvalues) and
    a nilpotent one (a pure delay chain: x dies)."""
    from gaintune.verification.mimo_products import divergence_rate

    rng = np.random.default_rng(1)
    Q, _ = np.linalg.qr(rng.normal(size=(80, 80)))

    def with_radius(rho: float) -> np.ndarray:
        return Q @ np.diag(np.r_[rho, np.linspace(-0.9, 0.9, 79)]) @ Q.T

    rate = divergence_rate(with_radius(1.05))
    assert rate is not None and rate == pytest.approx(1.05, rel=1e-6)
    assert divergence_rate(with_radius(0.999)) is None
    assert divergence_rate(with_radius(1.005)) is None  # 1.005^512 = 13: the eigenvalues decide
    assert divergence_rate(np.eye(80, k=-1)) is None


def test_search_check_screens_a_diverging_train_without_its_eigenvalues_and_the_verdict_never_does(
        monkeypatch) -> None:
    """On the 110-gain train, CMA-ES spent 86 % of its time in the eigenvalues of candidates that were far
    from stable. The search's (aimed) check now calls such a loop unstable from x <- A x alone: the same
    verdict, and a grade (UNSTABLE_VIOLATION + log1p(max Re pole)) within 1e-3 of the eigenvalues'. The
    full report (the verdict's) still takes the eigenvalues."""
    from gaintune.verification import mimo_sampled

    spec = load_spec(_train_spec())
    ev = Evaluator(spec)
    full = ev.layout.full((8.0 * ev.layout.initial_tuned())[None])[0]  # every gain x8: far from stable
    msr._CORES.clear()
    _, whole, _ = sampled_margins(ev.spec, ev.plant, ev.layout, full)
    eig_calls = []
    real = mimo_sampled.block_eigvals
    monkeypatch.setattr(mimo_sampled, "block_eigvals", lambda A: eig_calls.append(1) or real(A))
    _, aimed, _ = sampled_margins(ev.spec, ev.plant, ev.layout, full, aimed=True)
    assert not whole.stability.stable and whole.stability.method == "poles"
    assert not aimed.stability.stable and aimed.stability.method == "growth" and not eig_calls
    grade = [np.log1p(r.stability.max_real_pole) for r in (whole, aimed)]
    assert grade[1] == pytest.approx(grade[0], abs=1e-3)
