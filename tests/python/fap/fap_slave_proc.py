"""A FAP slave process for the cross-process tests.

usage: fap_slave_proc.py PORT ID

Prints ``ready`` once open, then one ``recv SRC HEX`` line per message. A
message from the master (0) is echoed back to it reversed. Commands on
stdin: ``send TO HEX`` (prints ``sent``), ``quit`` (or EOF) closes and exits 0.
"""
from __future__ import annotations

import sys
import threading

from fap_py import ClosedError, Slave


def main() -> int:
    path, sid = sys.argv[1], int(sys.argv[2])
    slave = Slave(path, 115200, id=sid)
    out_lock = threading.Lock()

    def say(line: str) -> None:
        with out_lock:
            sys.stdout.write(line + "\n")
            sys.stdout.flush()

    def commands() -> None:
        for line in sys.stdin:
            words = line.split()
            if words[:1] == ["send"]:
                slave.send(bytes.fromhex(words[2]), to=int(words[1]))
                slave.flush(timeout=10)
                say("sent")
            elif words[:1] == ["quit"]:
                break
        slave.close()           # ends the receive loop below

    threading.Thread(target=commands, daemon=True).start()
    say("ready")
    try:
        for msg in slave:
            say(f"recv {msg.source} {msg.data.hex()}")
            if msg.source == 0:
                slave.send(msg.data[::-1], to=0)
    except ClosedError:
        pass
    slave.close()
    say("bye")
    return 0


if __name__ == "__main__":
    sys.exit(main())
