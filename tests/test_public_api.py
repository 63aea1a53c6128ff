"""The public API: one import, and reading results does not load the search stack."""

from __future__ import annotations


def test_public_names_import_from_the_top_level():
    from gaintune import TuneResult, VerificationReport, load_spec, tune, verify, versions

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]})
    rep = verify(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}})
    assert isinstance(rep, VerificationReport) and rep.verdict == "pass"
    assert callable(tune) and TuneResult.__name__ == "TuneResult" and "numpy" in versions()


def test_verify_and_results_do_not_import_torch(fresh_python):
    code = ("import sys, json; from gaintune import load_spec, verify, TuneResult, VerificationReport; "
            "import gaintune.verification.cascade, gaintune.verification.analysis; "
            "print(json.dumps(['torch' in sys.modules, 'stable_baselines3' in sys.modules]))")
    assert fresh_python(code) == [False, False]


def test_verify_is_the_function_and_verification_the_package():
    """``gaintune.verify`` is the function itself (no callable module); its package is ``gaintune.verification``."""
    import inspect

    import gaintune
    import gaintune.verification

    assert inspect.isfunction(gaintune.verify) and gaintune.verify is gaintune.verification.verify
    assert inspect.ismodule(gaintune.verification) and not callable(gaintune.verification)


def test_all_lists_every_lazily_imported_name():
    """``__all__`` is spelled out for linters; it names exactly the names ``__getattr__`` imports."""
    import gaintune

    assert set(gaintune.__all__) == {"__version__", *gaintune._EXPORTS}
