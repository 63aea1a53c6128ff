"""``gaintune bench api``'s simulate phases: their options are checked before a server starts."""

from __future__ import annotations

import pytest

from gaintune.bench import api


@pytest.mark.parametrize("argv", [["--phases", "simulate,nope"], ["--phases", ","], ["--simulate-scenarios", "1,0"],
                                  ["--simulate-scenarios", "17"], ["--simulate-concurrency", "0"],
                                  ["--simulate-requests", "-1"]])
def test_bench_api_simulate_options_exit_2_before_starting_a_server(argv, capsys, monkeypatch):
    def no_server(*a, **k):
        raise AssertionError("the API server was started before the arguments were checked")

    monkeypatch.setattr(api, "start_server", no_server)
    monkeypatch.setattr(api, "_in_process_verify_ms", lambda *a, **k: 0.0)
    with pytest.raises(SystemExit) as exc:
        api.main(["--phases", "simulate", *argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.startswith(f"error: {argv[0]}: ") and "Traceback" not in err


def test_bench_api_simulate_spec_has_the_scenarios_asked_for():
    from gaintune.spec import load_spec

    spec = load_spec(api.simulate_spec(16))
    assert len(spec.scenarios) == 16 and all(sc.n_steps == 2000 for sc in spec.scenarios)
