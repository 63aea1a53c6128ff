"""Rules for the names a spec gives (the spec ``name`` and ``loops[].name``), shared with the exporters.

Names are written into the generated files that are pasted into firmware: inside
C ``/* */`` comments and MATLAB ``%`` comments, and, sanitised by :func:`ident`, into
C macro and MATLAB variable names. This module is the one place those rules live,
so validation (:mod:`gaintune.spec`) and the exporters (:mod:`gaintune.export`)
cannot drift apart; it sits in the spec layer so the spec never imports the export layer.
"""

from __future__ import annotations

import re
import unicodedata

__all__ = ["ident", "ident_key", "unsafe_char", "name_problem"]

#: Bidirectional-text controls: invisible, they make a comment display as code ("Trojan Source").
_BIDI = frozenset("\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069")
#: Readable names of the control characters most often met (unicodedata has no name for C0/C1 controls).
_CONTROL_NAMES = {"\n": "newline", "\r": "carriage return", "\t": "tab", "\x00": "NUL", "\x0b": "vertical tab",
                  "\x0c": "form feed", "\x1b": "escape", "\x7f": "delete", "\x85": "next line"}
#: C comment delimiters: a name holding one would end (or nest) the comment it is written into.
_C_COMMENT = ("*/", "/*")


def ident(name: str) -> str:
    """The identifier the exporters derive from ``name``.

    Every character other than ASCII letters, digits and ``_`` becomes ``_``; a leading
    digit (or an empty name) gets a ``_`` in front.

    Parameters
    ----------
    name : str
        A spec or loop name.

    Returns
    -------
    str
        A valid C and MATLAB identifier fragment (gains.h upper-cases it).
    """
    s = re.sub(r"[^0-9A-Za-z_]", "_", str(name))
    return s if s and not s[0].isdigit() else f"_{s}"


def ident_key(name: str) -> str:
    """What two loop names must not share: :func:`ident` upper-cased, as gains.h writes it (``GT_<NAME>_KP``).

    Parameters
    ----------
    name : str
        A loop name.

    Returns
    -------
    str
        The upper-cased identifier; equal keys mean equal C macro names.
    """
    return ident(name).upper()


def unsafe_char(text: str) -> str | None:
    """The first character of ``text`` that may not appear in a name written into a generated file, else None.

    Those are the C0 and C1 control characters (newline, carriage return, tab, NUL, ...),
    the Unicode line and paragraph separators and the bidirectional-text controls.

    Parameters
    ----------
    text : str
        The text to check.

    Returns
    -------
    str or None
        The offending character, or None when every character is allowed.
    """
    for ch in str(text):
        if ch in _BIDI or unicodedata.category(ch) in ("Cc", "Zl", "Zp"):
            return ch
    return None


def name_problem(text: str) -> str | None:
    """Why ``text`` cannot be a spec or loop name, or None when it can.

    Parameters
    ----------
    text : str
        The name to check.

    Returns
    -------
    str or None
        A sentence naming the problem and the fix, for a validation message.
    """
    ch = unsafe_char(text)
    if ch is not None:
        what = _CONTROL_NAMES.get(ch) or unicodedata.name(ch, "control")
        return (f"contains the control character U+{ord(ch):04X} ({what}); names are "
                "written into comments of gains.h and gains.m, so give printable text on one line")
    for delim in _C_COMMENT:
        if delim in text:
            return (f"contains {delim!r}, which would end or nest the C comment the name is written into in gains.h; "
                    "remove it")
    return None
