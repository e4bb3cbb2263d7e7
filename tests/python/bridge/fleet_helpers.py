"""Helpers of the fleet tests (issue 37): broker lists, a NATS server with its MQTT
listener, and the accounting of rows at a consumer by the (host, seq) rule."""
from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import threading
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

from mosquitto import free_port

NATS = shutil.which("nats-server", path=os.environ.get("PATH", "") + ":/usr/sbin:/usr/local/sbin")
QUIET_BUS = {"name": "line1", "port": "/dev/null", "protocol": "fap", "slaves": [1],
             "reopen_interval": 3600}   # rows come from Bridge.rx(): the bus is not the subject


def fleet_config(ports: Sequence[int], state_dir: str, host: str = "test", failover: Optional[dict] = None,
                 sparkplug: Optional[dict] = None, **broker: Any) -> Any:
    """A checked BridgeConfig with a [[broker]] list on 127.0.0.1:``ports`` (in that order)."""
    from fap_py.bridge.config import from_dict

    brokers = [dict({"url": f"mqtt://127.0.0.1:{p}", "reconnect_min": 0.05, "reconnect_max": 0.3,
                     "connect_timeout": 2.0, "keepalive": 5}, **broker) for p in ports]
    data: Dict[str, Any] = {"broker": brokers, "bridge": {"host": host, "state_dir": state_dir,
                                                          "stats_interval": 0.5},
                            "failover": dict({"attempts": 1, "failback_interval": 0.3, "drain": 1.0},
                                             **(failover or {})),
                            "bus": [dict(QUIET_BUS)]}
    if sparkplug is not None:
        data["sparkplug"] = sparkplug
    return from_dict(data)


def rx_rows(bridge: Any, first: int, count: int, node: int = 1) -> None:
    """``count`` received messages numbered ``first``.. (their data), in bus order."""
    for i in range(first, first + count):
        bridge.rx("line1", node, {"data": f"{i:06x}"})


def accounting(messages: List[Any], topic_suffix: str = "/rx") -> Dict[str, Any]:
    """What one consumer got, by the (host, seq) rule: the distinct rows (their data, in
    the order first seen), the duplicates, and whether the first deliveries were in order."""
    seen: Dict[Tuple[str, int], int] = {}
    order: List[int] = []
    dups = 0
    for m in list(messages):
        if not m.topic.endswith(topic_suffix):
            continue
        d = json.loads(m.payload)
        key = (d["host"], d["seq"])
        if key in seen:
            dups += 1
            continue
        seen[key] = int(d["data"], 16)
        order.append(d["seq"])
    return {"data": set(seen.values()), "seqs": order, "duplicates": dups,
            "in_order": order == sorted(order)}


class Nats:
    """nats-server with its MQTT listener (MQTT 3.1.1 only; JetStream holds the sessions)."""

    def __init__(self, workdir: str, start_timeout: float = 15.0) -> None:
        self.workdir = workdir
        os.makedirs(workdir, exist_ok=True)
        self.port = free_port()
        self.client_port = free_port()
        self.start_timeout = start_timeout
        self.proc: Optional[subprocess.Popen] = None
        self.log: List[str] = []
        self.conf = os.path.join(workdir, "nats.conf")
        with open(self.conf, "w") as f:
            f.write(f'server_name: "fap_test"\nlisten: "127.0.0.1:{self.client_port}"\n'
                    f'jetstream {{ store_dir: "{workdir}/js" }}\n'
                    f'mqtt {{ listen: "127.0.0.1:{self.port}" }}\n')

    def start(self) -> "Nats":
        self.proc = subprocess.Popen([NATS, "-c", self.conf], stderr=subprocess.STDOUT,
                                     stdout=subprocess.PIPE, text=True)
        ready = threading.Event()

        def read(proc: subprocess.Popen) -> None:
            for line in proc.stdout:
                self.log.append(line.rstrip())
                if "Server is ready" in line:
                    ready.set()
            ready.set()

        threading.Thread(target=read, args=(self.proc,), daemon=True).start()
        deadline = time.monotonic() + self.start_timeout
        ok = ready.wait(self.start_timeout) and self.proc.poll() is None
        while ok and time.monotonic() < deadline:   # the MQTT listener answers
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                break
            except OSError:
                time.sleep(0.05)
        if not ok:
            self.stop()
            raise AssertionError("nats-server did not start:\n" + "\n".join(self.log[-10:]))
        return self

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None

    def __enter__(self) -> "Nats":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
