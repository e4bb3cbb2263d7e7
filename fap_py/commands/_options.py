"""Option groups, output and errors shared by every ``fap`` subcommand.

One style for the whole command (docs/cli.md):

* the same option names everywhere: :func:`add_port_options` (``--port``,
  ``--baud``, ``--rs485``, ``--rts-before``, ``--rts-after``,
  ``--rts-polarity``), :func:`add_link_options` (``--timeout``,
  ``--retries``), :func:`add_output_options` (``--json``); ``-v/-vv`` and
  ``--debug`` are accepted before or after the subcommand
  (:func:`split_global_flags`);
* ``--baud`` is checked against the C core's baud table
  (``fap_port_baud_rate``), with a message that lists the rates that work;
* :func:`emit` prints one JSON object per line with ``--json``, else the
  human text;
* :func:`run_command` is the one error path: one line ``fap: error: ...``
  on stderr, an exit code from :data:`EXIT_CODES`, a traceback only with
  ``--debug``.

A subcommand module uses :func:`add_command` to create its parser (help
shows every default and the module's example), then the option groups it
needs, then ``set_defaults(func=...)``.
"""
from __future__ import annotations

import argparse
import errno
import json
import logging
import sys
import traceback
from dataclasses import asdict, is_dataclass
from enum import Enum
from typing import Any, Callable, Dict, List, NoReturn, Optional, Sequence, Tuple

from .._validate import baud_rates
from ..errors import FapError, FileError, InvalidValueError
from ..rs485 import DEFAULT_BAUD

#: Exit codes of every ``fap`` command (docs/cli.md).
EXIT_OK = 0           #: success
EXIT_BUS = 1          #: the operation failed on the bus (no reply, refused, CRC ...)
EXIT_USAGE = 2        #: bad arguments (unknown option, bad baud, value out of range)
EXIT_PORT = 3         #: port or file error (cannot open, busy, vanished)
EXIT_INTERRUPTED = 130  #: Ctrl-C / SIGINT

EXIT_CODES: Dict[int, str] = {
    EXIT_OK: "ok",
    EXIT_BUS: "the operation failed on the bus (no reply, refused, CRC error ...)",
    EXIT_USAGE: "usage error (bad arguments, unsupported baud rate)",
    EXIT_PORT: "port or file error (cannot open, busy, vanished)",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C)",
}

RS485_CHOICES = ("auto", "kernel", "soft", "none", "gpio")

log = logging.getLogger("fap_py.cli")


class UsageError(InvalidValueError):
    """A bad argument found after parsing (exit 2)."""


class BusError(FapError):
    """The operation failed on the bus, already reported or worth one line (exit 1)."""


# -- parsers -------------------------------------------------------------

class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Shows every default and keeps the example epilog as written."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        # no "(default: None/False)" noise on flags and optional values
        if action.default is None or action.default is False or action.default == argparse.SUPPRESS \
                or "%(default)" in text or "(default" in text:
            return text
        if isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            return text
        return text + " (default: %(default)s)"


class Parser(argparse.ArgumentParser):
    """argparse with the one error style: ``fap: error: ...`` and exit 2."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"fap: error: {message} (see '{self.prog} --help')\n")
        sys.exit(EXIT_USAGE)


def add_global_flags(parser: argparse.ArgumentParser, *, top: bool = False) -> None:
    """``-v/--verbose`` and ``--debug``; on subparsers for ``--help`` only,
    because :func:`split_global_flags` takes them out of argv wherever they are."""
    default: Any = 0 if top else argparse.SUPPRESS
    parser.add_argument("-v", "--verbose", action="count", default=default,
                        help="log more: -v info, -vv debug with every frame's wire bytes")
    parser.add_argument("--debug", action="store_true",
                        default=False if top else argparse.SUPPRESS,
                        help="show a traceback on error (and log at debug)")


def split_global_flags(argv: Sequence[str]) -> Tuple[List[str], int, bool]:
    """argv without ``-v``/``-vv``/``--verbose``/``--debug`` (anywhere before
    ``--``), the verbosity count and the debug flag."""
    rest: List[str] = []
    verbose, debug = 0, False
    it = iter(argv)
    for arg in it:
        if arg == "--":
            rest.append(arg)
            rest.extend(it)
            break
        if arg == "--verbose":
            verbose += 1
        elif len(arg) >= 2 and arg[0] == "-" and set(arg[1:]) == {"v"}:
            verbose += len(arg) - 1
        elif arg == "--debug":
            debug = True
        else:
            rest.append(arg)
    return rest, verbose, debug


def add_command(sub: "argparse._SubParsersAction[Any]", name: str, *, help: str,
                description: Optional[str] = None, example: str = "",
                aliases: Sequence[str] = ()) -> argparse.ArgumentParser:
    """A subcommand parser in the shared style: defaults shown, ``example``
    as the epilog, ``-v``/``--debug`` listed."""
    epilog = "example:\n" + "\n".join(f"  {line}" for line in example.strip().splitlines()) \
        if example else None
    p = sub.add_parser(name, help=help, description=description or help, epilog=epilog,
                       formatter_class=HelpFormatter, aliases=list(aliases))
    add_global_flags(p)
    return p


def add_actions(parser: argparse.ArgumentParser, dest: str) -> "argparse._SubParsersAction[Any]":
    """Sub-subcommands (``fap exec master`` ...), required."""
    return parser.add_subparsers(dest=dest, metavar="ACTION", required=True,
                                 parser_class=Parser)


# -- option groups -----------------------------------------------------------

def baud(text: str) -> int:
    """argparse type of ``--baud``: an int in the C core's baud table."""
    try:
        value = int(text, 10)
    except ValueError:
        value = -1
    rates = baud_rates()
    if value not in rates:
        raise argparse.ArgumentTypeError(
            f"unsupported baud rate {text!r}; supported: {', '.join(map(str, rates))}")
    return value


def _nonneg_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not v >= 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, not {text!r}")
    return v


def _nonneg_int(text: str) -> int:
    try:
        v = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, not {text!r}")
    return v


seconds = _nonneg_float
count = _nonneg_int


def positive(text: str) -> int:
    """argparse type: an int >= 1 (``--registers``: how many of a thing, none is no request)."""
    v = integer(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {text!r}")
    return v


def add_port_options(parser: argparse.ArgumentParser, *, baud_default: Optional[int] = DEFAULT_BAUD,
                     port_required: bool = True, rs485_default: str = "auto",
                     port_help: str = "serial device (e.g. /dev/ttyUSB0, or a `fap bus` port)",
                     baud_help: str = "line speed, bit/s") -> argparse._ArgumentGroup:
    """``--port PATH --baud N --rs485 MODE --rts-before MS --rts-after MS
    --rts-polarity {high,low}``; a command whose --baud has no fixed default
    (``baud_default=None``) says in ``baud_help`` what it falls back to."""
    g = parser.add_argument_group("serial port")
    g.add_argument("--port", metavar="PATH", required=port_required, help=port_help)
    g.add_argument("--baud", metavar="N", type=baud, default=baud_default, help=baud_help)
    g.add_argument("--rs485", choices=RS485_CHOICES, default=rs485_default,
                   help="transmitter switching: kernel RS-485 ioctl (auto falls back to none "
                   "where the driver has none), soft = RTS toggled by the library, "
                   "none = auto-direction transceiver, gpio = a GPIO line (--gpio-chip, "
                   "--gpio-line) is the DE/RE pin")
    g.add_argument("--rts-before", metavar="MS", type=seconds, default=0.0,
                   help="RTS asserted -> first bit, milliseconds")
    g.add_argument("--rts-after", metavar="MS", type=seconds, default=0.0,
                   help="last bit -> RTS released, milliseconds")
    g.add_argument("--rts-polarity", choices=("high", "low"), default="high",
                   help="RTS level while sending (--rs485 gpio: the DE line's)")
    g.add_argument("--gpio-chip", metavar="PATH",
                   help="--rs485 gpio: the GPIO character device of the DE/RE line "
                   "(e.g. /dev/gpiochip0)")
    g.add_argument("--gpio-line", metavar="N", type=count, default=0,
                   help="--rs485 gpio: the line offset on --gpio-chip")
    add_realtime_option(g)
    return g


def realtime_spec(text: str) -> str:
    """argparse type of ``--realtime``: a spec C's one parser accepts
    (``fap_port_rt_parse``), e.g. ``fifo:50,mlock,cpu=1``."""
    from ..rs485 import parse_realtime

    try:
        parse_realtime(text)
    except InvalidValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_realtime_option(group: Any) -> None:
    """``--realtime SPEC`` (docs/realtime.md): the engine's I/O thread (or the
    bus relay) at SCHED_FIFO/RR, mlockall, CPU affinity; refused at open
    without the privilege."""
    group.add_argument("--realtime", metavar="SPEC", type=realtime_spec, default=None,
                       help="real-time I/O thread: fifo:PRIO or rr:PRIO (1..99), mlock, "
                       "cpu=N[-M], comma-separated; needs CAP_SYS_NICE or RLIMIT_RTPRIO "
                       "(docs/realtime.md)")


def add_echo_option(group: argparse._ArgumentGroup) -> None:
    """``--echo-suppression`` in the serial port group of every command that
    sends (the port layer's ``echo_suppression``, which every engine uses)."""
    group.add_argument("--echo-suppression", action="store_true",
                        help="read back and drop our own bytes (2-wire adapters that hear "
                        "themselves)")


def add_link_options(parser: argparse.ArgumentParser, *, timeout_default: float = 0.1,
                     retries_default: int = 3) -> argparse._ArgumentGroup:
    """``--timeout S --retries N``."""
    g = parser.add_argument_group("link")
    g.add_argument("--timeout", metavar="S", type=seconds, default=timeout_default,
                   help="reply timeout per attempt, seconds")
    g.add_argument("--retries", metavar="N", type=count, default=retries_default,
                   help="extra attempts after a timeout or a damaged reply")
    return g


def add_output_options(parser: argparse.ArgumentParser) -> None:
    """``--json``."""
    parser.add_argument("--json", action="store_true",
                        help="machine-readable output: one JSON object per line")


def add_repeat_options(parser: argparse.ArgumentParser, *, count_default: int = 1) -> None:
    """``--count N --interval S`` for continuous polling."""
    parser.add_argument("--count", metavar="N", type=count, default=count_default,
                        help="how many times (0 = until Ctrl-C)")
    parser.add_argument("--interval", metavar="S", type=seconds, default=1.0,
                        help="pause between repetitions, seconds")


def rs485_from_args(args: argparse.Namespace, **extra: Any) -> Any:
    """The :class:`fap_py.RS485` line options (the library's
    ``fap_port_options``) from the port option group; ``extra`` sets other
    fields (``turnaround_us`` ...); ``--echo-suppression``, where the command
    has it, sets ``echo_suppression``."""
    from ..fap import RS485, RS485Mode

    if getattr(args, "echo_suppression", False):
        extra.setdefault("echo_suppression", True)

    mode = {"auto": RS485Mode.AUTO, "kernel": RS485Mode.KERNEL,
            "soft": RS485Mode.SOFT_RTS, "none": RS485Mode.NONE,
            "gpio": RS485Mode.GPIO}[args.rs485]
    chip = getattr(args, "gpio_chip", None)
    if mode == RS485Mode.GPIO and not chip:
        raise UsageError("--rs485 gpio needs --gpio-chip PATH (and --gpio-line N)")
    if chip is not None and mode != RS485Mode.GPIO:
        raise UsageError(f"--gpio-chip is for --rs485 gpio (the mode is {args.rs485}): add "
                         "--rs485 gpio, or drop --gpio-chip")
    if chip:
        from .._validate import check_gpio_line
        try:    # before the port opens: an error names the chip, not the serial port
            check_gpio_line(chip, args.gpio_line)
        except InvalidValueError as exc:
            raise UsageError(str(exc).replace("gpio_line", "--gpio-line", 1)) from None
        except FileError as exc:          # exit 3, naming the chip
            raise FileError(exc.errno or 0, f"--gpio-chip: {exc.why}", chip) from None
        extra.update(gpio_chip=chip, gpio_line=args.gpio_line)
    if getattr(args, "realtime", None):
        extra.setdefault("realtime", args.realtime)
    return RS485(mode=mode, rts_active_high=args.rts_polarity == "high",
                 delay_before_send_us=round(args.rts_before * 1000),
                 delay_after_send_us=round(args.rts_after * 1000), **extra)


# -- output --------------------------------------------------------------

def _jsonable(obj: Any) -> Any:
    if isinstance(obj, (bytes, bytearray, memoryview)):
        return bytes(obj).hex()
    if isinstance(obj, Enum):
        return obj.name.lower()
    if is_dataclass(obj) and not isinstance(obj, type):
        return asdict(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _prepare(obj: Any) -> Any:
    """Enums by name (an IntEnum would otherwise be written as its number)."""
    if isinstance(obj, Enum):
        return obj.name.lower()
    if isinstance(obj, dict):
        return {k: _prepare(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_prepare(v) for v in obj]
    return obj


def emit(args: argparse.Namespace, obj: Dict[str, Any], human_text: Optional[str]) -> None:
    """With ``--json``: ``obj`` as one JSON line (bytes as hex, enums by
    name); else ``human_text`` (nothing if None). Flushed either way, so a
    pipe sees each line at once."""
    if getattr(args, "json", False):
        text: Optional[str] = json.dumps(_prepare(obj), default=_jsonable, separators=(",", ":"))
    else:
        text = human_text
    if text is not None:
        print(text, flush=True)


def plural(n: int, word: str, words: Optional[str] = None) -> str:
    """``1 frame``, ``2 frames`` (``words`` for an irregular plural)."""
    return f"{n} {word if n == 1 else words or word + 's'}"


def detail(exc: BaseException, subject: str) -> str:
    """The error text without a leading ``subject: `` the caller already
    prints (``node 6 seq 0: no reply``, not ``node 6 seq 0: node 6: no reply``)."""
    text = str(exc)
    return text[len(subject) + 2:] if text.startswith(subject + ": ") else text


def hexbytes(text: str) -> bytes:
    """argparse type: bytes written as hex (spaces and ``:`` allowed)."""
    try:
        return bytes.fromhex(text.replace(":", " "))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not hex bytes: {text!r}") from None


def integer(text: str) -> int:
    """argparse type: an int in any base Python writes (``12``, ``0x0c``)."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None


# -- errors ----------------------------------------------------------------

_PORT_ERRNOS = {errno.ENOENT, errno.EACCES, errno.EPERM, errno.EBUSY, errno.EIO, errno.ENXIO,
                errno.ENODEV, errno.ENOTTY, errno.EISDIR, errno.ENOTDIR}


def exit_code_for(exc: BaseException) -> int:
    """The documented exit code of an exception that ends a command."""
    from ..errors import ClosedError, FapError, InvalidValueError, PortError

    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INTERRUPTED
    if isinstance(exc, UsageError):
        return EXIT_USAGE
    if isinstance(exc, BusError):
        return EXIT_BUS
    if isinstance(exc, (PortError, ClosedError)):
        return EXIT_PORT
    if isinstance(exc, InvalidValueError):
        return EXIT_USAGE
    if isinstance(exc, FapError):
        return EXIT_BUS
    if isinstance(exc, OSError):     # files (--capture, EEPROM dir), pyserial ports
        return EXIT_PORT
    try:
        import serial
        if isinstance(exc, serial.SerialException):
            return EXIT_PORT
    except ImportError:  # pragma: no cover - pyserial is a dependency
        pass
    return EXIT_BUS


def error_line(exc: BaseException) -> str:
    """``fap: error: ...``: one line, no ``[Errno N]`` prefix."""
    text = str(exc) or type(exc).__name__
    if isinstance(exc, OSError) and exc.strerror:
        text = exc.strerror
        if exc.filename and str(exc.filename) not in text:
            text = f"{exc.filename}: {text}"
    return f"fap: error: {text.splitlines()[0] if text else type(exc).__name__}"


_RS485_HINT = {
    "kernel": "the device has no kernel RS-485 (TIOCSRS485 refused: a pty or most USB "
              "adapters); use --rs485 soft (RTS toggled by the library) or none "
              "(auto-direction transceiver)",
    "soft": "the device has no RTS modem line (TIOCMBIS refused: a pty, say); use "
            "--rs485 none (auto-direction transceiver)",
}


def rs485_unsupported(exc: BaseException, args: argparse.Namespace) -> Optional[str]:
    """The one line for an ``--rs485 kernel|soft`` the device cannot do
    (ENOTTY from the port layer), or None for any other error."""
    mode = getattr(args, "rs485", None)
    if mode not in _RS485_HINT or not isinstance(exc, OSError) or exc.errno != errno.ENOTTY:
        return None
    port = getattr(args, "port", None) or getattr(exc, "filename", None) or "the port"
    return f"fap: error: {port}: --rs485 {mode}: {_RS485_HINT[mode]}"


def run_command(func: Callable[[argparse.Namespace], Optional[int]],
                args: argparse.Namespace) -> int:
    """Run a subcommand with the one error path of ``fap``."""
    debug = bool(getattr(args, "debug", False))
    try:
        return int(func(args) or 0)
    except KeyboardInterrupt:
        if debug:
            traceback.print_exc()
        return EXIT_INTERRUPTED
    except BrokenPipeError:   # `fap ... | head`: the reader left, not an error
        import os
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())   # no second error when Python flushes
        except OSError:  # pragma: no cover
            pass
        return EXIT_OK
    except Exception as exc:
        code = exit_code_for(exc)
        if debug:
            traceback.print_exc()
        hint = rs485_unsupported(exc, args)
        if hint is not None:               # exit 3: a port error
            sys.stderr.write(hint + "\n")
            return EXIT_PORT
        elif code == EXIT_BUS and not _known(exc):
            # not one of ours: a bug, say so rather than hide it
            sys.stderr.write(f"fap: error: internal error {type(exc).__name__}: {exc} "
                             "(rerun with --debug for the traceback)\n")
            return EXIT_BUS
        sys.stderr.write(error_line(exc) + "\n")
        return code


def _known(exc: BaseException) -> bool:
    from ..errors import FapError

    return isinstance(exc, (FapError, UsageError, BusError, OSError))
