"""A simulated G485 System-Slave, sans-I/O: events in, reply frames out.

:class:`SimDevice` holds the registers, modes, error word, check byte and
EEPROM image of one device and answers parser events
(:class:`~fap_py.g485.codec.Packet` / :class:`~fap_py.g485.codec.Discarded`)
with the bytes to send back (or None). :mod:`fap_py.g485.simulator` puts
devices on a port. Every behaviour the seed leaves open is decided in
``docs/g485.md``; the short version is in the comments here.
"""
from __future__ import annotations

import json
import logging
import os
import random
import stat
import threading
from typing import Any, Callable, Dict, Iterable, List, NamedTuple, Optional, Tuple, Union

from .._files import read_user_file
from .._validate import check_path
from ..errors import InvalidValueError
from . import codec
from .codec import BROADCAST, Discarded, ErrorBit, Packet, PacketKind, ParseIssue, SetCommand
from .errors import G485ValueError

log = logging.getLogger("fap_py.g485.sim")

EEPROM_FORMAT = "fap_py.g485.eeprom/1"


class RegisterSpec(NamedTuple):
    """Access rule of one register: ``access`` "R", "W" or "RW"; ``saved`` in EEPROM."""

    access: str
    initial: int
    saved: bool = True


#: discarded whole frames a device notes in its error word (other discards are not frames)
_DISCARD_ERRORS = {ParseIssue.BAD_CHECK: ErrorBit.BAD_CHECK, ParseIssue.UNKNOWN_PACKET: ErrorBit.MALFORMED}

#: seed V11: ProtocolVer, DeviceMainClass, DeviceSubClass, HardwareVer, SoftwareVer
DEFAULT_IDENTITY = (11, 1, 1, 1, 1)


#: the largest EEPROM file a device loads (the image is ~2 kB of JSON)
MAX_EEPROM_FILE = 1 << 20


def _eeprom_path(value: Any) -> str:
    """An EEPROM file path: a path without NUL, and a regular file if it exists
    (it is created at the first save, so its directory must exist). Refused up
    front, not at power-on or at a save that would fail: '', a directory,
    ``/dev/null``, ``/dev/zero``, a name that is not valid UTF-8 (bytes such as
    ``b'\\xff\\xfe'``, a lone surrogate), a file in a missing directory."""
    try:
        path = check_path(value, "eeprom_path")
    except InvalidValueError as exc:
        raise G485ValueError(str(exc)) from None
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        shown = value if isinstance(value, bytes) else path
        raise G485ValueError(f"eeprom_path {shown!r} is not a valid UTF-8 file name") from None
    try:
        st = os.stat(path)
    except FileNotFoundError:
        parent = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(parent):
            raise G485ValueError(f"eeprom_path {path!r}: its directory {parent!r} does not exist "
                                 "(the file is created at the first save, the directory is not)"
                                 ) from None
        return path
    except OSError as exc:
        raise G485ValueError(f"eeprom_path {path!r}: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise G485ValueError(f"eeprom_path {path!r} is not a regular file")
    if st.st_size > MAX_EEPROM_FILE:
        raise G485ValueError(f"eeprom_path {path!r}: {st.st_size} bytes, more than "
                             f"the {MAX_EEPROM_FILE} an EEPROM image may have")
    return path


class SimDevice:
    """One simulated G485 device.

    :param address: factory ID (register 7) when no EEPROM file exists yet.
    :param identity: values of the read-only registers 1..5.
    :param private: access rules of registers 8..100 (default: RW, 0, saved).
    :param eeprom_path: file holding the EEPROM image (JSON); loaded at power-on,
        written by Set 0x7C and 0x7D. None: EEPROM kept in memory only.
    :param bulk_discard_rate: chance that a read, write or error-word request
        is dropped in bulk transmission mode (drawn from ``seed``).
    :param wake_up_loss: emulate baud detection above 28,800 baud: the first
        burst heard after power-on or reset is lost.
    :param on_apply: called as ``on_apply(device, first, last)`` whenever
        registers are "performed" (at once in real-time mode, at 0x77 otherwise).
    """

    def __init__(self, address: int = 1, *, identity: Tuple[int, int, int, int, int] = DEFAULT_IDENTITY,
                 private: Optional[Dict[int, Union[RegisterSpec, Tuple]]] = None,
                 eeprom_path: Optional[Union[str, os.PathLike]] = None,
                 bulk_discard_rate: float = 0.25, seed: int = 0, wake_up_loss: bool = False,
                 on_apply: Optional[Callable[["SimDevice", int, int], None]] = None) -> None:
        _whole(address, "device address", codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS)
        try:
            ident = tuple(identity)
        except TypeError:
            raise G485ValueError("identity must be 5 byte values (registers 1..5)") from None
        if len(ident) != 5 or not all(type(v) is int and 0 <= v <= 255 for v in ident):
            raise G485ValueError("identity must be 5 byte values (registers 1..5)")
        if isinstance(bulk_discard_rate, bool) or not isinstance(bulk_discard_rate, (int, float)) \
                or not 0.0 <= bulk_discard_rate <= 1.0:  # also false for NaN
            raise G485ValueError(f"bulk_discard_rate must be a probability 0..1, not {bulk_discard_rate!r}")
        _whole(seed, "seed", -(1 << 63), (1 << 63) - 1)
        if not isinstance(wake_up_loss, bool):
            raise G485ValueError(f"wake_up_loss must be a bool, not {type(wake_up_loss).__name__}")
        if on_apply is not None and not callable(on_apply):
            raise G485ValueError("on_apply must be callable or None")
        if eeprom_path is not None:
            eeprom_path = _eeprom_path(eeprom_path)
        if private is not None and not isinstance(private, dict):
            raise G485ValueError(f"private must be a dict of register specs, not {type(private).__name__}")
        self.specs: List[RegisterSpec] = [RegisterSpec("", 0, False)] * 101
        for reg, value in enumerate(ident, start=1):
            self.specs[reg] = RegisterSpec("R", value, False)
        self.specs[6] = RegisterSpec("W", 0, False)
        self.specs[7] = RegisterSpec("RW", address, True)
        for reg in range(8, 101):
            self.specs[reg] = RegisterSpec("RW", 0, True)
        for reg, spec in (private or {}).items():
            _whole(reg, "private register", 8, 100)
            try:
                spec = RegisterSpec(*spec)
            except TypeError:
                raise G485ValueError(f"bad spec for register {reg}: {spec!r}") from None
            if (spec.access not in ("R", "W", "RW") or type(spec.initial) is not int
                    or not 0 <= spec.initial <= 255 or not isinstance(spec.saved, bool)):
                raise G485ValueError(f"bad spec for register {reg}: {spec}")
            self.specs[reg] = spec
        self.eeprom_path: Optional[str] = eeprom_path
        self.bulk_discard_rate = bulk_discard_rate
        self.wake_up_loss = wake_up_loss
        self.on_apply = on_apply
        self._rng = random.Random(seed)
        self.lock = threading.RLock()  # the port thread writes, tests and hooks read
        self._write_only = [r for r, spec in enumerate(self.specs) if spec.access == "W"]
        self.factory_image = bytes(s.initial for s in self.specs)
        # power-on state
        self.eeprom = bytearray(self.factory_image)
        self.baud_locked = False
        self.error_word = 0
        self.check_byte = 0
        self.packets_handled = 0
        self.discarded_in_bulk = 0
        self.commands: List[int] = []  # values written to register 6, in order performed
        eeprom_ok = self._load_eeprom()
        self._power_on()
        if not eeprom_ok:
            self.error_word |= ErrorBit.EEPROM

    # -- state ----------------------------------------------------------------

    def _power_on(self) -> None:
        """What power-on and Set 0x7B (reset) do."""
        self.registers = bytearray(self.eeprom)
        for reg, spec in enumerate(self.specs):
            if not spec.saved:
                self.registers[reg] = spec.initial
        self.registers[6] = 0
        self.applied = bytearray(self.registers)  # the values the device acts on
        self.address = self.registers[7]
        self.real_time = True
        self.bulk_mode = False
        self._pending: Dict[int, int] = {}
        self.asleep = self.wake_up_loss
        self.error_word = 0
        # the check byte survives a reset: the Set that caused it is what a handshake checks

    def _load_eeprom(self) -> bool:
        """Read the EEPROM file if there is one; False if it is unusable."""
        if not self.eeprom_path or not os.path.exists(self.eeprom_path):
            return True
        try:
            raw = read_user_file(self.eeprom_path, limit=MAX_EEPROM_FILE, what="EEPROM file")
            self.eeprom, self.baud_locked = self._parse_eeprom(raw)
            return True
        except OSError as exc:
            why = getattr(exc, "why", "") or exc.strerror or str(exc)
        except ValueError as exc:
            why = str(exc)
        log.warning("EEPROM file %s unusable (%s): factory settings", self.eeprom_path, why)
        return False

    def _parse_eeprom(self, raw: bytes) -> Tuple[bytearray, bool]:
        """(image, baud_locked) of an EEPROM file's bytes; ValueError with the reason
        in words (never a Python exception's text) when it is not one."""
        try:
            doc = json.loads(raw.decode("utf-8"))
        except UnicodeDecodeError:
            raise ValueError("not UTF-8 text") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"not JSON: {exc.msg} at line {exc.lineno}") from None
        if not isinstance(doc, dict):
            raise ValueError(f"not an EEPROM image: a JSON {type(doc).__name__.replace('dict', 'object')}"
                             f", not an object with \"format\": \"{EEPROM_FORMAT}\"")
        if doc.get("format") != EEPROM_FORMAT:
            raise ValueError(f"format {doc.get('format')!r}, not {EEPROM_FORMAT!r}")
        regs = doc.get("registers")
        if not isinstance(regs, dict):
            raise ValueError('"registers" must be an object of register: value')
        image = bytearray(self.factory_image)
        for key, value in regs.items():
            if not key.isdigit() or not codec.MIN_REGISTER <= int(key) <= codec.MAX_REGISTER:
                raise ValueError(f"register {key!r} outside {codec.MIN_REGISTER}.."
                                 f"{codec.MAX_REGISTER}")
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 255:
                raise ValueError(f"register {key}: value {value!r} is not 0..255")
            if self.specs[int(key)].saved:
                image[int(key)] = value
        if not codec.MIN_SLAVE_ADDRESS <= image[7] <= codec.MAX_SLAVE_ADDRESS:
            raise ValueError(f"ID register 7 = {image[7]}, not {codec.MIN_SLAVE_ADDRESS}.."
                             f"{codec.MAX_SLAVE_ADDRESS}")
        locked = doc.get("baud_locked", False)
        if not isinstance(locked, bool):
            raise ValueError(f'"baud_locked" must be true or false, not {locked!r}')
        return image, locked

    def _save_eeprom(self) -> None:
        """Set 0x7C: the saved registers' current values go to EEPROM."""
        for reg, spec in enumerate(self.specs):
            if spec.saved:
                self.eeprom[reg] = self.registers[reg]
        self._write_eeprom_file()

    def _write_eeprom_file(self) -> None:
        if not self.eeprom_path:
            return
        doc = {"format": EEPROM_FORMAT, "baud_locked": self.baud_locked,
               "registers": {str(r): self.eeprom[r] for r, s in enumerate(self.specs) if s.saved}}
        tmp = f"{self.eeprom_path}.tmp"
        try:
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(doc, f, indent=1)
            os.replace(tmp, self.eeprom_path)
        except OSError as exc:
            log.warning("EEPROM save to %s failed: %s", self.eeprom_path, exc)
            self.error_word |= ErrorBit.EEPROM

    def _perform(self, first: int, last: int) -> None:
        """Make registers first..last act (real-time write, or Set 0x77)."""
        self.applied[first:last + 1] = self.registers[first:last + 1]
        if first <= 6 <= last:
            self.commands.append(self.registers[6])
            self.registers[6] = 0
        if first <= 7 <= last:
            self.address = self.registers[7]
        if self.on_apply is not None:
            self.on_apply(self, first, last)

    def set_register(self, register: int, value: int) -> None:
        """Change a register from the device side (a sensor value, say)."""
        _whole(register, "register", codec.MIN_REGISTER, codec.MAX_REGISTER)
        _whole(value, "register value", 0, 255)
        with self.lock:
            self.registers[register] = value
            self.applied[register] = value

    # -- events -----------------------------------------------------------------

    def handle(self, event: Union[Packet, Discarded]) -> Optional[bytes]:
        """Process one parser event; return the reply frame to send, if any."""
        if not isinstance(event, (Packet, Discarded)):
            raise G485ValueError(f"event must be a Packet or Discarded, not {type(event).__name__}")
        lock = self.lock
        lock.acquire()  # explicit acquire/release: cheaper than ``with`` on the hot path
        try:
            return self._handle(event)
        finally:
            lock.release()

    def _handle(self, event: Union[Packet, Discarded]) -> Optional[bytes]:
        if self.asleep:
            self.asleep = False  # baud detection consumed this burst
            return None
        if isinstance(event, Discarded):
            # a whole frame for this device (or broadcast) that it cannot use: not executed,
            # not answered, and the check byte keeps its old value
            bit = _DISCARD_ERRORS.get(event.issue)
            if bit and event.data[2] != codec.SMA_R and event.data[2] >> 1 in (self.address, BROADCAST):
                self.error_word |= bit
            return None
        kind = event.kind
        target = event.address
        if target == codec.MASTER_ADDRESS:
            return None  # another device's reply
        if target != self.address and target != BROADCAST:
            return None
        self.packets_handled += 1
        if target == BROADCAST and kind not in (PacketKind.WRITE, PacketKind.SET):
            self.error_word |= ErrorBit.BROADCAST_READ
            return None
        if (self.bulk_mode and kind in (PacketKind.WRITE, PacketKind.READ_REQUEST,
                                        PacketKind.ERROR_WORD_REQUEST)
                and self._rng.random() < self.bulk_discard_rate):
            self.discarded_in_bulk += 1
            self.error_word |= ErrorBit.DISCARDED
            return None
        if kind is PacketKind.READ_REQUEST:
            return self._read(event.pid, event.data[0])
        if kind is PacketKind.WRITE:
            if self._write(event.pid, event.data):
                self.check_byte = event.check  # SDOC: received correctly and accepted
            # refused (read-only register, bad value): the check byte keeps its old value,
            # which is how the master's handshake learns of the refusal
            return None
        if kind is PacketKind.HANDSHAKE_REQUEST:
            return codec.encode_handshake_response(self.check_byte)
        if kind is PacketKind.ERROR_WORD_REQUEST:
            reply = codec.encode_error_word_response(self.error_word & 0xFFFF)
            self.check_byte = reply[-1]  # SDIC
            return reply
        if kind is PacketKind.SET:
            self.check_byte = event.check
            self._set(SetCommand(event.pid))
            return None
        return None  # pragma: no cover - every request kind handled above

    def _read(self, register: int, count: int) -> Optional[bytes]:
        if count < 1 or register + count - 1 > codec.MAX_REGISTER:
            self.error_word |= ErrorBit.REGISTER_RANGE
            return None
        end = register + count
        values = self.registers[register:end]
        for reg in self._write_only:
            if register <= reg < end:
                values[reg - register] = 0  # write-only reads as 0
        reply = codec.frame(codec.SMA_R, register, bytes(values))
        self.check_byte = reply[-1]  # SDIC
        return reply

    def _write(self, register: int, data: bytes) -> bool:
        """Store (and maybe perform) a write; False if the whole packet is refused."""
        last = register + len(data) - 1
        for reg in range(register, last + 1):
            if self.specs[reg].access == "R":
                self.error_word |= ErrorBit.READ_ONLY
                return False  # the whole packet is refused
        if register <= 7 <= last and not codec.MIN_SLAVE_ADDRESS <= data[7 - register] <= codec.MAX_SLAVE_ADDRESS:
            self.error_word |= ErrorBit.BAD_VALUE
            return False
        self.registers[register:last + 1] = data
        if self.real_time:
            self._perform(register, last)
        else:
            for reg in range(register, last + 1):
                self._pending[reg] = data[reg - register]
        return True

    def _set(self, cmd: SetCommand) -> None:
        if cmd is SetCommand.FACTORY_RESET:
            self.eeprom = bytearray(self.factory_image)
            self.baud_locked = False
            self.registers = bytearray(self.factory_image)
            self._save_eeprom()
            self._power_on()
        elif cmd is SetCommand.SAVE_EEPROM:
            self._save_eeprom()
        elif cmd is SetCommand.RESET:
            self._power_on()
        elif cmd is SetCommand.CLEAR_ERROR_WORD:
            self.error_word = 0
        elif cmd is SetCommand.REAL_TIME_WRITE:
            self.real_time = True  # writes still pending wait for 0x77
        elif cmd is SetCommand.NON_REAL_TIME_WRITE:
            self.real_time = False
        elif cmd is SetCommand.APPLY_WRITES:
            pending, self._pending = self._pending, {}
            for first, last in _runs(sorted(pending)):
                self._perform(first, last)
        elif cmd is SetCommand.CONTROL_MODE:
            self.bulk_mode = False
        elif cmd is SetCommand.BULK_MODE:
            self.bulk_mode = True
        elif cmd is SetCommand.LOCK_BAUD_RATE:
            self.baud_locked = True  # stored at once: survives reset, factory reset clears it
            self._write_eeprom_file()

    @property
    def pending_writes(self) -> Dict[int, int]:
        """Registers written in Non-Real-Time mode, not yet performed."""
        with self.lock:
            return dict(self._pending)


def _whole(value: object, what: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise G485ValueError(f"{what} must be an int, not {type(value).__name__}")
    if not lo <= value <= hi:
        raise G485ValueError(f"{what} {value} outside {lo}..{hi}")
    return value


def _runs(regs: Iterable[int]) -> List[Tuple[int, int]]:
    """Consecutive runs of register numbers as (first, last)."""
    out: List[Tuple[int, int]] = []
    for reg in regs:
        if out and out[-1][1] == reg - 1:
            out[-1] = (out[-1][0], reg)
        else:
            out.append((reg, reg))
    return out
