"""Owning a serial device: a UUCP lock file holding our pid (``/var/lock/LCK..ttyX``,
the convention minicom, picocom and ModemManager honour), on top of the flock and
TIOCEXCL the C port layer takes (``RS485.exclusive``). Private.

:func:`fap_py._holder.holder` answers "who holds this device?" for a refused opener.
"""
from __future__ import annotations

import errno
import logging
import os

from .._holder import DEFAULT_LOCK_DIR, _lock_name, _read_pid, describe
from ..errors import PortBusyError, PortError

log = logging.getLogger(__name__)

class UucpLock:
    """The lock file ``LCK..<device>`` in ``lock_dir`` with our pid (10 chars + newline).

    A file whose pid is dead is stale and taken over; a live one raises
    :class:`~fap_py.errors.PortBusyError` naming that pid. ``release`` removes
    only our own file.
    """

    def __init__(self, device: str, lock_dir: str = DEFAULT_LOCK_DIR) -> None:
        self.path = _lock_name(device, lock_dir)
        self.device = device
        self._mine = False

    def acquire(self) -> None:
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
            except FileExistsError:
                pid = _read_pid(self.path)
                if pid is not None and pid != os.getpid():
                    raise PortBusyError(errno.EBUSY, f"port busy: held by {describe(pid)} "
                                        f"(lock file {self.path})", self.device) from None
                log.info("%s: stale lock file taken over", self.path)
                try:
                    os.unlink(self.path)
                except FileNotFoundError:
                    pass
                continue
            except OSError as exc:
                raise PortError(exc.errno or errno.EACCES,
                                f"cannot create the lock file {self.path}: {exc.strerror} "
                                "(--lock-dir names another directory)", self.device) from None
            try:
                os.write(fd, b"%10d\n" % os.getpid())
            finally:
                os.close(fd)
            self._mine = True
            return
        raise PortBusyError(errno.EBUSY, f"port busy: lock file {self.path} keeps coming back", self.device)

    def release(self) -> None:
        if self._mine:
            self._mine = False
            if _read_pid(self.path) == os.getpid():
                try:
                    os.unlink(self.path)
                except OSError:
                    pass

    def __enter__(self) -> "UucpLock":
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
