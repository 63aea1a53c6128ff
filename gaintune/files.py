"""Safe file input and output: what gaintune writes stays in its folder, what it reads is bounded.

Two rules for every file a user or a foreign party can place:

* **Writes are atomic and never follow a link at the destination.** The data goes to a
  temporary file in the destination's own folder, which is then renamed over the destination
  with :func:`os.replace`. A rename replaces a symlink planted at the destination; it never
  writes through it, so a link to a file elsewhere cannot redirect the output. A reader sees
  the old file or the new one, never half of one.
* **Reads take regular files only, up to a size cap.** ``/dev/zero``, a FIFO or a 4 GB file is
  refused with a message that names the limit, before anything is read into memory.
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from pathlib import Path

from gaintune.errors import SpecError

__all__ = ["MAX_INPUT_BYTES", "read_bytes_bounded", "read_text_bounded", "write_atomic"]

#: Largest input file gaintune reads (spec, gains, result.json, agent). A spec or a result is
#: kilobytes; 10 MB leaves room for a 5,000-loop verification while refusing runaway inputs.
MAX_INPUT_BYTES = 10 * 1024 * 1024


def write_atomic(path: str | Path, data: bytes | str, *, encoding: str = "utf-8") -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename.

    A symlink at ``path`` is replaced by the new file, never followed; the file the link
    pointed to is left untouched. The folder must exist. A device, pipe, socket or folder at
    ``path`` (or a link to one, such as ``/dev/stdout``) is refused, never replaced: renaming
    over ``/dev/null`` as root would remove the device.

    Parameters
    ----------
    path
        Destination file.
    data
        Bytes, or text encoded with ``encoding``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OSError
        ``EINVAL`` for a destination that is not a regular file, a link or absent; the
        errors of the folder (no permission, full disk) as they come.
    """
    path = Path(path)
    _check_destination(path)
    raw = data.encode(encoding) if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; outputs are ordinary files to share
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _check_destination(path: Path) -> None:
    """Refuse a destination that exists and is neither a regular file nor a link to one (or a dangling link)."""
    try:
        mode = path.stat().st_mode  # follows a link: /dev/stdout is a link to a pipe or terminal
    except FileNotFoundError:
        return  # absent, or a dangling link: the rename puts a new file there
    except OSError:
        return  # e.g. a link loop, or no access: the rename replaces the link or reports the error
    if not stat.S_ISREG(mode):
        raise OSError(errno.EINVAL, "not a regular file (a device, pipe, socket or folder); give a file path",
                      str(path))


def read_bytes_bounded(path: str | Path, field: str, limit: int = MAX_INPUT_BYTES) -> bytes:
    """Read a regular file of at most ``limit`` bytes.

    Raises
    ------
    SpecError
        Naming ``field``: the path is missing, is not a regular file (a device, FIFO, socket or
        folder), or is larger than ``limit``.
    """
    path = Path(path)
    try:
        # O_NONBLOCK: opening a FIFO with no writer must not hang before the type check
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise SpecError(field, f"no file at {path}") from None
    except OSError as exc:
        raise SpecError(field, f"cannot read {path}: {exc.strerror}") from None
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):  # before fdopen, which refuses a folder with a bare "[Errno 21] ...: 3"
        os.close(fd)
        raise SpecError(field, f"{path} is not a regular file; give a regular file of at most {_size(limit)}, "
                        "not a device, pipe or folder")
    with os.fdopen(fd, "rb") as fh:
        if info.st_size > limit:
            raise SpecError(field, f"{path} is {info.st_size:,} bytes; the limit is {_size(limit)}")
        data = fh.read(limit + 1)  # the file may have grown since fstat
    if len(data) > limit:
        raise SpecError(field, f"{path} is larger than the limit of {_size(limit)}")
    return data


def _size(n: int) -> str:
    """``10 MB`` for whole mebibytes, else ``1,234 bytes``."""
    return f"{n >> 20} MB" if n and n % (1 << 20) == 0 else f"{n:,} bytes"


def read_text_bounded(path: str | Path, field: str, limit: int = MAX_INPUT_BYTES) -> str:
    """:func:`read_bytes_bounded`, decoded as UTF-8 (an undecodable file is a SpecError)."""
    data = read_bytes_bounded(path, field, limit)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SpecError(field, f"{path} is not UTF-8 text (byte {exc.start})") from None
