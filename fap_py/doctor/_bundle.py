"""``--bundle FILE``: the evidence as a tar to attach to a bug report.

Every file a check read (under its analysed path), the kernel log read and the
report (``report.json``, one finding per line). Secrets are masked in every text:
``password``/``passwd``/``token``/``secret``/``key``/``psk``/``auth`` values (``k=v``,
``k: v``, ``k v``, TOML and JSON forms) and a URL's ``user:password@`` and a command line's ``--password VALUE``."""
from __future__ import annotations

import io
import json
import re
import tarfile
import time
from typing import Iterable

from ..errors import FileError
from ._context import Context, _read_regular
from ._finding import Finding

#: the largest file put in the bundle (its start)
BUNDLE_FILE_MAX = 1 << 20
MASK = "********"
#: files never put in a bundle, whatever a config's include line named
NEVER = {"/etc/shadow", "/etc/gshadow", "/etc/shadow-", "/etc/gshadow-"}

_KEY = r"[\w.-]*(?:pass(?:word|wd|phrase)?|token|secret|api[_-]?key|private[_-]?key|psk|auth\w*|credential\w*)[\w.-]*"
_KV_RE = re.compile(r'(?im)^(\s*["\']?' + _KEY + r'["\']?\s*(?:=|:|\s)\s*)("?)([^"\n#]*)("?)')
_INLINE_RE = re.compile(r'(?i)(["\']?' + _KEY + r'["\']?\s*[=:]\s*)("?)([^"\s,}]+)("?)')
_OPT_RE = re.compile(r"(?i)(--?" + _KEY + r"[ =])(\S+)")
_URL_RE = re.compile(r"(?i)(\b[a-z][a-z0-9+.-]*://[^/\s:@]+:)([^@\s/]+)(@)")


def mask(text: str) -> str:
    """``text`` with the values of secret-looking keys and URL passwords masked."""
    text = _URL_RE.sub(lambda m: m.group(1) + MASK + m.group(3), text)
    text = _OPT_RE.sub(lambda m: m.group(1) + MASK, text)
    text = _KV_RE.sub(lambda m: m.group(1) + m.group(2) + (MASK if m.group(3).strip() else "")
                      + m.group(4), text)
    return _INLINE_RE.sub(lambda m: m.group(1) + m.group(2) + MASK + m.group(4), text)


def _add(tar: tarfile.TarFile, name: str, text: str) -> None:
    data = mask(text).encode("utf-8")
    info = tarfile.TarInfo(name)
    info.size = len(data)
    info.mtime = int(time.time())
    info.mode = 0o644
    tar.addfile(info, io.BytesIO(data))


def write(path: str, ctx: Context, findings: Iterable[Finding]) -> int:
    """Write the bundle; the number of evidence files in it. FileError when the
    file cannot be written."""
    n = 0
    try:
        with tarfile.open(path, "w:gz") as tar:
            report = "\n".join(json.dumps(f.as_event(), sort_keys=True) for f in findings)
            _add(tar, "fap-doctor/report.json", report + "\n")
            for analysed, host in sorted(ctx.files_read.items()):
                if analysed in NEVER:
                    continue
                text = _read_regular(host, BUNDLE_FILE_MAX,
                                     tail=analysed in ("kernel-log", "/var/log/kern.log", "/dmesg",
                                                       "/var/log/dmesg"))
                if text is None:
                    continue
                name = "kernel-log" if analysed == "kernel-log" else analysed.lstrip("/")
                _add(tar, f"fap-doctor/root/{name}", text)
                n += 1
    except OSError as exc:
        raise FileError(exc.errno or 5, f"--bundle: {exc.strerror or exc}", path) from None
    return n
