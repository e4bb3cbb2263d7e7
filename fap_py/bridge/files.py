"""The files a bridge configuration names, opened with a type check and a size bound.

A path in bridge.toml may point anywhere (``/dev/zero``, a FIFO, a
directory, a 10 GB log): every file is opened without blocking, must be a
regular file and is read up to a bound, so a wrong path is one clear line
instead of a hang or a memory blow-up. ``--check`` uses the same checks
and creates nothing.
"""
from __future__ import annotations

import errno
import os
import stat
from typing import Optional

from .._files import read_user_file
from ..errors import FileError, InvalidTypeError, InvalidValueError, PortError

CONFIG_MAX = 1 << 20        #: bridge.toml
SECRET_MAX = 64 << 10       #: password_file
TLS_FILE_MAX = 1 << 20      #: ca, cert, key


class BridgeFileError(PortError):
    """A file or directory named in the configuration cannot be used (exit 3)."""

    def __init__(self, err: int, field: str, path: str, why: str) -> None:
        super().__init__(err, f"{field}: {path}: {why}")
        self.path = path
        self.field = field


def text_path(path: object, field: str = "path") -> str:
    """``path`` (str or os.PathLike of str) as a str; InvalidTypeError otherwise,
    BridgeFileError (a bad file, exit 3) for an empty path or one holding a NUL."""
    if not isinstance(field, str):
        raise InvalidTypeError(f"field must be a str, not {type(field).__name__}")
    if isinstance(path, os.PathLike):
        path = os.fspath(path)
    if not isinstance(path, str):
        raise InvalidTypeError(f"{field} must be a path (str), not {type(path).__name__}")
    if not path:
        raise BridgeFileError(errno.ENOENT, field, "''", "an empty path")
    if "\0" in path:
        raise BridgeFileError(errno.EINVAL, field, repr(path), "a path cannot hold a NUL byte")
    return path


def read_bounded(path: str, limit: int, field: str) -> bytes:
    """The content of the regular file ``path``, at most ``limit`` bytes (else BridgeFileError)."""
    path = text_path(path, field)
    if isinstance(limit, bool) or not isinstance(limit, int) or not 0 <= limit <= 1 << 30:
        raise InvalidValueError(f"limit must be an integer in 0..{1 << 30}, not {limit!r:.40}")
    try:                               # the package's one bounded read of a named file
        return read_user_file(path, limit=limit, what=field)
    except FileError as exc:
        raise BridgeFileError(exc.errno or errno.EIO, field, path, exc.why or exc.strerror or str(exc)) from None


def check_state_dir(path: str, field: str = "bridge.state_dir") -> None:
    """``path`` is (or can be created as) a writable directory; creates nothing."""
    path = text_path(path, field)
    probe: Optional[str] = os.path.abspath(path)
    while probe is not None:
        try:
            st = os.stat(probe)
        except FileNotFoundError:
            parent = os.path.dirname(probe)
            probe = None if parent == probe else parent
            continue
        except (OSError, ValueError) as exc:
            raise BridgeFileError(getattr(exc, "errno", None) or errno.EINVAL, field, path, str(exc)) from None
        if not stat.S_ISDIR(st.st_mode):
            raise BridgeFileError(errno.ENOTDIR, field, path, f"{probe} is not a directory")
        if not os.access(probe, os.W_OK | os.X_OK):
            raise BridgeFileError(errno.EACCES, field, path, f"{probe} is not writable")
        return
    raise BridgeFileError(errno.ENOENT, field, path, "no existing parent directory")


def check_port(path: str, field: str) -> None:
    """``path`` exists and is a character device (a serial port or a pty); opens nothing."""
    path = text_path(path, field)
    try:
        st = os.stat(path)
    except (OSError, ValueError) as exc:
        raise BridgeFileError(getattr(exc, "errno", None) or errno.EINVAL, field, path,
                              getattr(exc, "strerror", None) or str(exc)) from None
    if not stat.S_ISCHR(st.st_mode):
        raise BridgeFileError(errno.ENODEV, field, path, "not a character device (a serial port)")


__all__ = ["BridgeFileError", "CONFIG_MAX", "SECRET_MAX", "TLS_FILE_MAX", "check_port",
           "check_state_dir", "read_bounded", "text_path"]
