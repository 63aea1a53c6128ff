"""Forged agent files for the tests of issue 24 (a foreign agent.zip ran code): pickled code where SB3 unpickles."""

from __future__ import annotations

import base64
import io
import json
import os
import shlex
import zipfile
from pathlib import Path

import torch


class RunsCode:
    """Unpickling this runs a shell command that creates ``marker``: what SB3's own loader would do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {shlex.quote(str(self.marker))}",))


def rewrite(src: Path, dst: Path, **members: bytes | None) -> Path:
    """A copy of the zip ``src`` with ``members`` replaced (None: removed) or added."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for info in zin.infolist():
            if info.filename not in members:
                zout.writestr(info, zin.read(info))
        for name, data in members.items():
            if data is not None:
                zout.writestr(name, data)
    return dst


def pickled_code_in_data(src: Path, marker: Path) -> bytes:
    """``src``'s data JSON with every cloudpickled entry (policy class, spaces, ...) replaced by code."""
    import cloudpickle

    with zipfile.ZipFile(src) as z:
        data = json.loads(z.read("data"))
    payload = base64.b64encode(cloudpickle.dumps(RunsCode(marker))).decode()
    for value in data.values():
        if isinstance(value, dict) and ":serialized:" in value:
            value[":serialized:"] = payload
    return json.dumps(data).encode()


def torch_saved(obj) -> bytes:
    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()
