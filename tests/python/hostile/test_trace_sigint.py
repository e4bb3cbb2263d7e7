"""Issue 26 item 12: with -vv, a Ctrl-C that lands in the wire-trace hook
ends the command with exit 130.

Before: the KeyboardInterrupt was raised inside the cffi callback, which
printed it and dropped it; the command went on and exited 1. The SIGINT here
is sent by a logging handler on ``fap_py.wire`` (it runs inside the hook), so
it lands there every time.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.timeout(60)

# a handler that presses Ctrl-C from inside the hook, at the first frame traced
PRELUDE = textwrap.dedent("""
    import logging, os, signal, sys
    class CtrlC(logging.Handler):
        fired = False
        def emit(self, record):
            if not CtrlC.fired:
                CtrlC.fired = True
                os.kill(os.getpid(), signal.SIGINT)
    logging.getLogger("fap_py.wire").addHandler(CtrlC())
    from fap_py.vbus import VirtualBus
    bus = VirtualBus(ports=2)
""")


def run(body: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", PRELUDE + textwrap.dedent(body)],
                          capture_output=True, text=True, timeout=50)


def test_api_ctrl_c_in_hook_reaches_the_caller() -> None:
    r = run("""
        logging.getLogger("fap_py.wire").setLevel(logging.DEBUG)
        from fap_py import execasync
        from fap_py.rs485 import RS485, RS485Mode
        m = execasync.Master(bus.paths[0], timeout=0.2, retries=2, rs485=RS485(mode=RS485Mode.NONE))
        try:
            m.transact(3, b"x")
        except KeyboardInterrupt:
            print("interrupted", CtrlC.fired)
        except Exception as exc:
            print("other", type(exc).__name__)
        else:
            print("returned")
    """)
    assert r.stdout.strip() == "interrupted True", (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("argv", [["exec", "scan", "--first", "1", "--last", "3", "--timeout", "0.2"],
                                  ["mikroc", "master", "--address", "3", "--count", "3"]])
def test_cli_vv_ctrl_c_in_hook_exits_130(argv: list) -> None:
    r = run(f"""
        from fap_py import cli
        code = cli.main(["-vv", *{argv!r}, "--port", bus.paths[0], "--rs485", "none"])
        print("exit", code, CtrlC.fired)
        sys.exit(code)
    """)
    assert r.returncode == 130, (r.returncode, r.stdout, r.stderr[-2000:])
    assert "Traceback" not in r.stderr, r.stderr[-2000:]


def test_a_deferred_ctrl_c_is_raised_when_the_c_call_returns() -> None:
    """The guard only marks a Ctrl-C that landed in the hook; the handle wrapper of the
    C call that ran the hook raises it on the way out (no thread watching the stack)."""
    import threading

    from fap_py._handle import DeferredSigint
    from fap_py.vbus import VirtualBus

    threads = threading.active_count()
    with VirtualBus(ports=2) as bus:
        DeferredSigint.pending = True           # what _SigintGuard does inside the hook
        with pytest.raises(KeyboardInterrupt):
            bus.fileno()                        # any C call through NativeHandle._call
        assert not DeferredSigint.pending
        assert bus.stats.bytes_in == 0          # delivered once, the handle still usable
    assert threading.active_count() == threads
