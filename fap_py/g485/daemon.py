"""G485 on a bus a daemon owns (``fap serve --protocol g485``, docs/daemon.md): what
``G485Master("fapd://...")`` returns (also exported as ``fap_py.g485.DaemonG485Master``,
as each protocol package exports its daemon client)."""
from __future__ import annotations

import dataclasses
import enum
import threading
from typing import Any, Dict, Iterable, List, Optional, Tuple, Union

from .. import errors as _errors
from .._daemon_life import DaemonLife
from . import codec
from . import errors as g485_errors
from .codec import Data, SetCommand
from .errors import G485ValueError
from .transaction import Check, MasterStats, as_check


def _from_wire(err: Dict[str, Any]) -> BaseException:
    """A G485 error the daemon named: the same class, its message, its fields."""
    cls = getattr(g485_errors, str(err.get("type")), None)
    text = str(err.get("message", ""))
    if not (isinstance(cls, type) and issubclass(cls, _errors.FapError)):
        return _errors.FapError(text)
    exc = cls.__new__(cls)
    Exception.__init__(exc, text)
    for k in ("expected", "got", "address", "word"):
        if k in err:
            setattr(exc, k, err[k])
    if issubclass(cls, g485_errors.G485FrameError):
        try:
            exc.frame = bytes.fromhex(str(err.get("frame", "")))   # type: ignore[attr-defined]
        except ValueError:
            exc.frame = b""                                         # type: ignore[attr-defined]
    return exc


_WIRE_ERRORS = {n: _from_wire for n, c in vars(g485_errors).items()
                if isinstance(c, type) and issubclass(c, _errors.FapError)}


def _data(data: Data) -> str:
    return codec._as_data(data).hex()          # the codec's one reading of register data


def _check(check: Union[Check, str, None]) -> Optional[str]:
    return None if check is None else as_check(check, Check.HANDSHAKE).value


def _command(command: Union[SetCommand, int, str]) -> Any:
    if isinstance(command, enum.Enum):
        return int(command.value)
    if isinstance(command, (int, str)) and not isinstance(command, bool):
        return command
    raise G485ValueError(f"command must be a SetCommand, int or name, not {type(command).__name__}")


class DaemonG485Master(DaemonLife):
    """The System-Master's calls, each one transaction on the daemon's session (its
    timeout and retries unless given per call). ``weight``, ``priority``, ``token`` as
    for :class:`fap_py.execasync.DaemonMaster`; the line options are the daemon's."""

    def __init__(self, port: Any, baudrate: int = 115200, *, weight: Optional[int] = None,
                 priority: Optional[int] = None, token: Optional[str] = None, **options: Any) -> None:
        from ..serve._client import Connection

        if isinstance(baudrate, bool) or not isinstance(baudrate, int) or baudrate <= 0:
            raise G485ValueError(f"baudrate must be a positive int, not {baudrate!r}")
        self._conn = Connection(port, protocol="g485", weight=weight, priority=priority, token=token,
                                name="g485 master", errors=_WIRE_ERRORS)
        self.name = self._conn.url
        # the per-call defaults a G485Master takes at construction (the rest is the daemon's line)
        self._defaults = {"timeout": options.get("timeout"), "retries": options.get("retries"),
                          "check": _check(options.get("check"))}
        self._counts = dict.fromkeys((f.name for f in dataclasses.fields(MasterStats)), 0)
        self._lock = threading.Lock()
        self._close_hooks: List[Any] = []

    _TAKES = {"handshake": ("timeout", "retries"), "read": ("timeout", "retries", "check"),
              "write": ("timeout", "retries", "check"), "error_word": ("timeout", "retries", "check"),
              "set": ("timeout", "retries", "check"), "scan": ("timeout",)}

    def _call(self, method: str, **args: Any) -> Any:
        for k in self._TAKES.get(method, ()):
            if args.get(k) is None and self._defaults.get(k) is not None:
                args[k] = self._defaults[k]
        args = {k: v for k, v in args.items() if v is not None}
        try:
            answer = self._conn.call("g485", method=method, args=args)
        except _errors.FapError as exc:
            self._add(getattr(exc, "daemon_answer", {}))
            raise
        self._add(answer)
        return answer.get("value")

    def _add(self, answer: Dict[str, Any]) -> None:
        with self._lock:
            for k, v in (answer.get("stats") or {}).items():
                if k in self._counts and isinstance(v, int):
                    self._counts[k] += v

    @property
    def stats(self) -> MasterStats:
        """This client's share of the daemon session's counters."""
        with self._lock:
            return MasterStats(**self._counts)

    def handshake(self, address: int, *, timeout: Optional[float] = None,
                  retries: Optional[int] = None) -> int:
        return int(self._call("handshake", address=address, timeout=timeout, retries=retries))

    def read(self, address: int, register: int, count: int = 1, *, check: Union[Check, str, None] = None,
             timeout: Optional[float] = None, retries: Optional[int] = None) -> bytes:
        return bytes.fromhex(self._call("read", address=address, register=register, count=count,
                                        check=_check(check), timeout=timeout, retries=retries))

    def read_register(self, address: int, register: int, **kwargs: Any) -> int:
        return self.read(address, register, 1, **kwargs)[0]

    def write(self, address: int, register: int, data: Data, *, check: Union[Check, str, None] = None,
              timeout: Optional[float] = None, retries: Optional[int] = None) -> None:
        self._call("write", address=address, register=register, data=_data(data), check=_check(check),
                   timeout=timeout, retries=retries)

    def error_word(self, address: int, *, check: Union[Check, str, None] = None,
                   timeout: Optional[float] = None, retries: Optional[int] = None) -> int:
        return int(self._call("error_word", address=address, check=_check(check), timeout=timeout,
                              retries=retries))

    def check_error_word(self, address: int, **kwargs: Any) -> None:
        word = self.error_word(address, **kwargs)
        if word:
            raise g485_errors.DeviceErrorWordError(address, word)

    def set(self, address: int, command: Union[SetCommand, int, str], *, check: Union[Check, str, None] = None,
            guard: Optional[bool] = None, timeout: Optional[float] = None, retries: Optional[int] = None,
            factory_address: Optional[int] = None) -> None:
        self._call("set", address=address, command=_command(command), check=_check(check), guard=guard,
                   timeout=timeout, retries=retries, factory_address=factory_address)

    def scan(self, addresses: Iterable[int] = range(codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS + 1), *,
             timeout: Optional[float] = None, retries: Optional[int] = 0) -> List[int]:
        try:
            addrs = [int(a) for a in addresses]
        except (TypeError, ValueError):
            raise G485ValueError("addresses must be ints") from None
        return [int(a) for a in self._call("scan", addresses=addrs, timeout=timeout, retries=retries)]

    def believed_check_byte(self, address: int) -> Optional[int]:
        """The check byte the daemon's session thinks device ``address`` holds (None:
        unknown); another client's transactions move it too."""
        if isinstance(address, bool) or not isinstance(address, int):
            raise G485ValueError(f"address must be an int, not {type(address).__name__}")
        value = self._conn.call("believed_check_byte", address=address).get("value")
        return None if value is None else int(value)

    def broadcast_write(self, register: int, data: Data) -> None:
        self.write(codec.BROADCAST, register, data)

    def broadcast_set(self, command: Union[SetCommand, int, str], repeats: int = 1) -> None:
        self._call("broadcast_set", command=_command(command), repeats=repeats)

    def sync_write(self, writes: Iterable[Tuple[int, int, Data]], *, check: Union[Check, str, None] = None,
                   apply_repeats: int = 1, back_to_real_time: bool = False) -> None:
        try:
            w = [[a, r, _data(d)] for a, r, d in writes]
        except (TypeError, ValueError):
            raise G485ValueError("writes must be (address, register, data) triples") from None
        self._call("sync_write", writes=w, check=_check(check), apply_repeats=apply_repeats,
                   back_to_real_time=back_to_real_time)

    def change_id(self, address: int, new_address: int, *, save: bool = False,
                  check: Union[Check, str, None] = None) -> None:
        self._call("change_id", address=address, new_address=new_address, save=save, check=_check(check))

    def send_raw(self, data: bytes) -> None:
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise G485ValueError(f"data must be bytes-like, not {type(data).__name__}")
        self._call("send_raw", data=bytes(data).hex())

    def send_wake_up(self) -> None:
        self._call("send_wake_up")

    @property
    def fd(self) -> None:
        """No port fd here: :class:`~fap_py.g485.aio.AsyncG485Master` on a ``fapd://`` URL
        runs these blocking calls in its one worker thread (the daemon itself has none)."""
        return None

    def on_close(self, hook: Any) -> None:
        """Call ``hook()`` when :meth:`close` runs (the asyncio front end's)."""
        if not callable(hook):
            raise G485ValueError(f"hook must be callable, not {type(hook).__name__}")
        self._close_hooks.append(hook)

    def _closed(self) -> None:
        hooks, self._close_hooks = self._close_hooks, []
        for hook in hooks:
            hook()
