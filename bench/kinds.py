"""The exchange kinds ``python -m bench`` measures: labels, frame sizes, floors.

A leaf module (imports nothing of the bench): the runner, the report and
the README generator all read the kinds from here.
"""
from __future__ import annotations

from typing import Any, Dict, Optional, Tuple

# kind -> (label, request bytes, reply bytes, silence chars per exchange, floor kind)
C_KINDS = {
    "bare": ("bare C write/read (floor)", 15, 15, 0, None),
    "fap-poll": ("FAP poll cycle", 15, 15, 0, "bare"),
    "fap-data": ("FAP DATA round trip", 38, 38, 0, "bare"),
    "exec": ("exec async", 16, 16, 0, "bare"),
    "mikroc": ("mikroC RS-485", 8, 8, 0, "bare"),
    "modbus": ("libmodbus RTU (10 regs)", 8, 25, 0, "bare"),
}
# bench_g485 runs: kind -> (label, req, rep, silence, floor, server argv tail, client factory name)
PY_KINDS = {
    "py-bare": ("bare Python write/read (floor)", 7, 16, 0, None, ["--serve", "canned"], "bare"),
    "g485": ("G485 (fap_py, check=none)", 7, 16, 0, "py-bare", None, "g485"),
    "minimalmodbus": ("minimalmodbus RTU", 8, 25, 0, "py-bare", ["--serve", "modbus"], "minimalmodbus"),
    "pymodbus": ("pymodbus sync RTU", 8, 25, 0, "py-bare", ["--serve", "modbus"], "pymodbus"),
    "dynamixel": ("Dynamixel SDK 1.0", 8, 16, 0, "py-bare", ["--serve", "dxl"], "dynamixel"),
}
ALL_KINDS = tuple(C_KINDS) + tuple(PY_KINDS)
#: what --quick runs: every engine of the project, libmodbus and the two floors;
#: the Python peers (each a few seconds of imports and slow exchanges) only in the full run
QUICK_KINDS = ("bare", "fap-poll", "fap-data", "exec", "mikroc", "modbus", "py-bare", "g485")
#: the Python modules a Python peer needs
PEER_MODULES = {"minimalmodbus": "minimalmodbus", "pymodbus": "pymodbus", "dynamixel": "dynamixel_sdk"}
PEER_HELP = {
    "modbus": "libmodbus: apt-get install libmodbus-dev, then meson setup --reconfigure build",
    "minimalmodbus": "pip install minimalmodbus",
    "pymodbus": "pip install pymodbus",
    "dynamixel": "pip install dynamixel-sdk",
}

BASE = "base:"   # a C kind run with the --baseline build's bench_wire


def spec(kind: str) -> Tuple[Any, ...]:
    base = kind.startswith(BASE)
    k = kind[len(BASE):] if base else kind
    t = C_KINDS.get(k) or PY_KINDS[k]
    return (t[0] + " [baseline build]",) + tuple(t[1:]) if base else t


def is_c(kind: str) -> bool:
    return kind in C_KINDS or kind.startswith(BASE)


def label(kind: str) -> str:
    return spec(kind)[0]


def floor_of(kind: str) -> Optional[str]:
    return spec(kind)[4]


def limit(kind: str, baud: int) -> float:
    spec_ = spec(kind)
    return baud / (10.0 * (spec_[1] + spec_[2] + spec_[3]))


def floor_rate(kind: str, baud: int, rows: Dict[str, Any]) -> Optional[float]:
    """Exchanges/s the bare floor would reach with this kind's frame sizes:
    the wire time of its bytes plus the floor's own measured per-exchange
    overhead (its exchange time minus its wire time)."""
    fl = floor_of(kind)
    if not fl or fl not in rows or "rate" not in rows[fl]:
        return None
    overhead = 1.0 / rows[fl]["rate"]["median"] - 1.0 / limit(fl, baud)
    return 1.0 / (1.0 / limit(kind, baud) + max(0.0, overhead))
