"""Fuzz findings F05 and F06: spec and loop names are written into gains.h and gains.m.

F05: a name holding a newline or ``*/`` became live code in the exports; now validation rejects
control characters and C comment delimiters in ``name`` and ``loops[].name``, naming the field.
F06: two loop names that sanitise to one identifier ("a-b", "a b") gave duplicate macros in gains.h
and overwrote a loop's gains in gains.m; now the second is rejected at ``loops[1].name``.
"""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from gaintune.errors import problem_details
from gaintune.spec import load_spec

BASE = {"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}], "scenario": {"dt": 0.05, "horizon": 5}}
CASCADE = {"plant": {"ss": {"A": [[0, 1], [0, -2]], "B": [[0], [1]], "C": [[1, 0], [0, 1]], "outputs": ["pos", "vel"]}},
           "scenario": {"dt": 0.05, "horizon": 5}, "search": {"budget": 60, "n_envs": 8}}

#: Newline, CR, tab, NUL, escape, DEL, C1 NEL, Unicode line separator, right-to-left override.
CONTROL = ["a\nb", "a\rb", "a\tb", "a\x00b", "a\x1bb", "a\x7fb", "a\x85b", "a\u2028b", "a\u202eb"]


def _errors(data: dict) -> list[dict[str, str]]:
    with pytest.raises(ValidationError) as info:
        load_spec(data)
    return problem_details(info.value)


@pytest.mark.parametrize("name", CONTROL + ["a*/b", "a/*b", "evil */ #error injected /* "])
def test_f05_loop_name_with_control_character_or_comment_delimiter_is_rejected_at_the_field(name: str) -> None:
    errs = _errors({**BASE, "loops": [{"type": "pi", "name": name}]})
    assert [e["loc"] for e in errs] == ["loops.0.name"], errs
    assert "loop name" in errs[0]["msg"] and "Value error" not in errs[0]["msg"]
    assert "\n" not in errs[0]["msg"]  # the message itself stays on one line (the name is shown as repr)


@pytest.mark.parametrize("name", CONTROL + ["evil */ #error injected /* "])
def test_f05_spec_name_with_control_character_or_comment_delimiter_is_rejected_at_the_field(name: str) -> None:
    errs = _errors({**BASE, "name": name})
    assert [e["loc"] for e in errs] == ["name"], errs
    assert "spec name" in errs[0]["msg"]


def test_f05_message_says_which_character_and_the_fix() -> None:
    msg = _errors({**BASE, "loops": [{"type": "pi", "name": "a*/\n#error x\n/*"}]})[0]["msg"]
    assert "U+000A" in msg and "newline" in msg and "one line" in msg


def test_f05_description_is_not_restricted_it_is_never_exported() -> None:
    assert load_spec({**BASE, "description": "line one\nline two */"}).description.startswith("line one")


@pytest.mark.parametrize("names", [("a-b", "a b"), ("speed", "Speed"), ("x.1", "x_1"), ("é", "è"), ("1a", "_1a")])
def test_f06_loop_names_with_one_identifier_are_rejected_naming_the_second_loop(names: tuple[str, str]) -> None:
    from gaintune.spec.names import ident_key

    loops = [{"type": "p", "measure": "pos", "name": names[0]}, {"type": "pi", "measure": "vel", "name": names[1]}]
    errs = _errors({**CASCADE, "loops": loops})
    assert [e["loc"] for e in errs] == ["loops.1.name"], errs
    msg = errs[0]["msg"]
    assert "loops[0].name" in msg and repr(names[0]) in msg and "becomes _" in msg and ident_key(names[1]) in msg


def test_f06_the_check_uses_the_exporters_identifier_function() -> None:
    from gaintune.export import common
    from gaintune.spec.names import ident

    assert common._ident is ident  # one sanitiser: validation cannot drift from what gains.h writes


def test_ordinary_names_still_load() -> None:
    loops = [{"type": "p", "measure": "pos", "name": "position (outer)"}, {"type": "pi", "measure": "vel", "name": "vitesse é"}]
    spec = load_spec({**CASCADE, "name": "Motor 3 - rev. B / 2024", "loops": loops})
    assert [lp.name for lp in spec.loops] == ["position (outer)", "vitesse é"]
    from gaintune.spec.names import name_problem

    assert name_problem("a * / b") is None and name_problem("plain") is None


def test_exact_duplicate_loop_names_keep_their_message() -> None:
    loops = [{"type": "p", "measure": "pos", "name": "a"}, {"type": "pi", "measure": "vel", "name": "a"}]
    assert "unique" in _errors({**CASCADE, "loops": loops})[0]["msg"]


def test_f05_f06_cli_exits_2_naming_the_field(tmp_path) -> None:
    import yaml
    from typer.testing import CliRunner

    from gaintune import cli

    loops = [{"type": "p", "measure": "pos", "name": "a-b"}, {"type": "pi", "measure": "vel", "name": "a b"}]
    p = tmp_path / "spec.yaml"
    p.write_text(yaml.safe_dump({**CASCADE, "loops": loops}))
    res = CliRunner().invoke(cli.app, ["tune", str(p), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "error: loops.1.name: " in res.stderr, res.stderr
    assert not (tmp_path / "o" / "gains.h").exists()
