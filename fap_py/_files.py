"""Reading a file the user named, bounded. Private.

Every file fap_py reads because a user named it (a capture, an EEPROM image,
a config) goes through :func:`read_user_file`: opened without blocking (a
FIFO cannot hang the open), checked to be a regular file (``/dev/zero``, a
directory, a terminal are refused) and read to at most ``limit`` bytes (a
file that grows past it while read is refused too). The error is one
:class:`~fap_py.errors.FileError` naming the file and what is wrong.
"""
from __future__ import annotations

import errno
import os
import stat
from typing import BinaryIO, Union

from ._validate import check_path
from .errors import FileError

__all__ = ["open_user_file", "read_user_file"]

PathArg = Union[str, bytes, "os.PathLike[str]", "os.PathLike[bytes]"]


def _error(err: int, what: str, why: str, shown: str) -> FileError:
    """FileError ``shown: what: why``, with ``why`` kept as ``.why`` (the bridge words
    its own errors around it)."""
    exc = FileError(err, f"{what}: {why}", shown)
    exc.why = why
    return exc


def open_user_file(path: PathArg, *, limit: int, what: str) -> "tuple[str, BinaryIO]":
    """(the path as shown, the regular file ``path`` open for binary reading),
    checked to hold at most ``limit`` bytes; for callers that stream the file.

    Raises :class:`FileError` (missing, unreadable, not a regular file, over
    ``limit``), :class:`~fap_py.errors.InvalidValueError` for a bad path.
    """
    shown = check_path(path, what)
    raw = os.fsencode(shown)
    try:
        fd = os.open(raw, os.O_RDONLY | os.O_CLOEXEC | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError as exc:
        raise _error(exc.errno or errno.EIO, what, exc.strerror or str(exc), shown) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
            raise _error(errno.EISDIR if stat.S_ISDIR(st.st_mode) else errno.EINVAL, what, kind, shown)
        if st.st_size > limit:
            raise _error(errno.EFBIG, what, f"{st.st_size} bytes, more than the {limit} allowed", shown)
        return shown, os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_user_file(path: PathArg, *, limit: int, what: str) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them.

    Raises :class:`FileError` (missing, unreadable, not a regular file, over
    ``limit``), :class:`~fap_py.errors.InvalidValueError` for a bad path.
    """
    shown, fh = open_user_file(path, limit=limit, what=what)
    with fh:
        try:
            data = fh.read(limit + 1)
        except OSError as exc:
            raise _error(exc.errno or errno.EIO, what, exc.strerror or str(exc), shown) from None
    if len(data) > limit:
        raise _error(errno.EFBIG, what, f"grew past the {limit} bytes allowed", shown)
    return data
