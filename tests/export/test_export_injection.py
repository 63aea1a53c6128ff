"""Fuzz findings F05 and F06 at the exporters (defence in depth behind the name rules of the spec).

F05: a spec or loop name holding a newline or ``*/`` was written into gains.h and gains.m as live code
(``#error injected`` compiled as a directive; a line escaped MATLAB's ``%`` comment). F06: two loops
with one identifier gave duplicate macros. Validation now rejects such names (tests/spec/test_spec_names.py);
these tests bypass it, as a spec built in code or saved before the rules would, and check the files stay inert.
"""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
from types import SimpleNamespace

import pytest
from pydantic import ValidationError

from gaintune.export import ExportError, export_gains, export_result
from gaintune.export.c import _c_comment
from gaintune.spec import load_spec

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed: cannot check the header compiles")

SPEC_NAME = 'evil */ #error injected /* \n#error spec ??/\n"""\nimport os\n"""'
LOOP_NAME = "a*/\n#error x\n/*\r\n#error y\x00\u202e"
REASON = 'fails */\n#error reason "q" ??/ \\'
BASE = {"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}], "scenario": {"dt": 0.05, "horizon": 5}}


def _hostile_spec():
    """A valid spec whose names are then set without validation (pydantic does not validate assignment)."""
    spec = load_spec(BASE)
    spec.name = SPEC_NAME
    spec.loops[0].name = LOOP_NAME
    return spec, {LOOP_NAME: {"Kp": 1.0, "Ki": 0.5}}


def _gcc_syntax(tmp_path, header: str) -> subprocess.CompletedProcess:
    (tmp_path / "gains.h").write_text(header)
    (tmp_path / "use.c").write_text('#include "gains.h"\nint main(void) { return GT_N_LOOPS; }\n')
    return subprocess.run(["gcc", "-fsyntax-only", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic",
                           str(tmp_path / "use.c")], capture_output=True, text=True, cwd=tmp_path)


def _no_directive_but_the_header_own(header: str) -> None:
    directives = [ln.strip().split()[0] for ln in header.splitlines() if ln.lstrip().startswith("#")]
    assert set(directives) <= {"#ifndef", "#define", "#include", "#endif"}, directives
    # with comments and string literals removed (as the compiler reads it), no injected text is left
    code = re.sub(r'/\*.*?\*/|"(?:\\.|[^"\\\n])*"', " ", header, flags=re.S)
    assert "#error" not in code and "import os" not in code, code


def test_f05_c_header_with_hostile_names_has_no_injected_directive() -> None:
    spec, gains = _hostile_spec()
    header = export_gains(spec, gains, "c", verdict="fail", reasons=[REASON])
    _no_directive_but_the_header_own(header)
    # outside string literals, every "*/" closes a comment the exporter opened: none comes from a name
    no_strings = re.sub(r'"(?:\\.|[^"\\\n])*"', '""', header)
    assert no_strings.count("*/") == no_strings.count("/*")


@needs_gcc
@pytest.mark.parametrize("verdict", ["pass", "fail"])
def test_f05_c_header_with_hostile_names_compiles(tmp_path, verdict: str) -> None:
    spec, gains = _hostile_spec()
    res = _gcc_syntax(tmp_path, export_gains(spec, gains, "c", verdict=verdict, reasons=[REASON]))
    assert res.returncode == 0, res.stderr


def test_f05_matlab_with_hostile_names_keeps_every_name_in_its_comment() -> None:
    spec, gains = _hostile_spec()
    text = export_gains(spec, gains, "matlab", verdict="fail", reasons=[REASON])
    for line in text.splitlines():
        if "#error" in line or "import os" in line:
            # in a % comment, or inside the quoted verdict_reason string
            assert line.startswith("%") or line.startswith("verdict_reason = '"), line
    assert "\u202e" not in text and "\x00" not in text and "\r" not in text


def test_f05_python_export_docstring_cannot_be_closed_by_the_name() -> None:
    spec, gains = _hostile_spec()
    tree = ast.parse(export_gains(spec, gains, "python", verdict="fail", reasons=[REASON]))
    assert isinstance(tree.body[0], ast.Expr) and "evil" in tree.body[0].value.value
    assert all(isinstance(node, ast.Assign) for node in tree.body[1:]), ast.dump(tree)[:500]


@pytest.mark.parametrize("text", ["*/", "/*", "*/*/", "/*/", "**//**", "a*/\n/*b", "??/", "???/", "*\n/"])
def test_c_comment_text_can_neither_close_nor_open_a_comment(text: str) -> None:
    safe = _c_comment(text)
    assert "*/" not in safe and "/*" not in safe and "??" not in safe and "\n" not in safe


def test_f05_old_result_with_hostile_names_is_refused_not_exported() -> None:
    """A result saved before the name rules: its spec is validated again on export, so no file is produced."""
    data = {**BASE, "name": SPEC_NAME, "loops": [{"type": "pi", "name": LOOP_NAME}]}
    old = SimpleNamespace(spec=data, gains={LOOP_NAME: {"Kp": 1.0, "Ki": 0.5}})
    with pytest.raises(ValidationError) as info:
        export_result(old, "c", checked=("pass", {"reasons": []}))
    locs = {".".join(map(str, e["loc"])) for e in info.value.errors()}
    assert locs == {"name", "loops.0.name"}


def _colliding_spec():
    spec = load_spec({"plant": {"ss": {"A": [[0, 1], [0, -2]], "B": [[0], [1]], "C": [[1, 0], [0, 1]], "outputs": ["pos", "vel"]}},
                      "loops": [{"type": "p", "measure": "pos", "name": "a-b"}, {"type": "pi", "measure": "vel", "name": "a_c"}],
                      "scenario": {"dt": 0.05, "horizon": 5}})
    spec.loops[1].name = "a b"  # bypass the validation that now rejects it
    return spec, {"a-b": {"Kp": 2.0}, "a b": {"Kp": 1.0, "Ki": 0.5}}


@pytest.mark.parametrize("fmt", ["c", "matlab"])
def test_f06_colliding_identifiers_are_refused_by_the_exporter(fmt: str) -> None:
    spec, gains = _colliding_spec()
    with pytest.raises(ExportError) as info:
        export_gains(spec, gains, fmt)
    assert info.value.field == "loops.1.name" and "A_B" in str(info.value).upper()


def test_f06_case_only_difference_is_refused_for_c_and_allowed_for_matlab() -> None:
    spec, gains = _colliding_spec()
    spec.loops[1].name = "A-b"
    gains = {"a-b": {"Kp": 2.0}, "A-b": {"Kp": 1.0, "Ki": 0.5}}
    with pytest.raises(ExportError):
        export_gains(spec, gains, "c")
    assert len(re.findall(r"^gt_\w+ = struct", export_gains(spec, gains, "matlab"), re.M)) == 2


@pytest.mark.parametrize("prefix", ["g t", "1gt", "gt\n#error p", ""])
def test_c_prefix_must_be_an_identifier(prefix: str) -> None:
    spec = load_spec(BASE)
    with pytest.raises(ExportError) as info:
        export_gains(spec, {"loop0": {"Kp": 1.0, "Ki": 0.5}}, "c", prefix=prefix)
    assert info.value.field == "prefix"
