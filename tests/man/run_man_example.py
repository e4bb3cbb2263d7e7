#!/usr/bin/env python3
"""Compile a man3 page's EXAMPLE with the page's own SYNOPSIS line and check
that it waits without spinning (issue 32 item 4: fapInit(3)'s example looped
on the non-blocking fapRx, 86 % of a core).

    run_man_example.py PAGE.3 DESTDIR WORKDIR

PAGE.3 is an installed page (roff). Its SYNOPSIS says
``cc -I<includedir> app.c -L<libdir> -lfap -lpthread -lrt``: those directories,
under DESTDIR (a scratch ``meson install --destdir``), must hold fap.h and
libfap.so, so the line is right for the install's prefix. The EXAMPLE block
is compiled with exactly those flags (-Wall -Wextra -Werror), started on a
pty, and once it has put its first frame on the line (it runs: fapInit and
fapConfig succeeded), its CPU time over a window of WINDOW_S must stay under
MAX_CPU_S. A busy loop burns the whole window (a share of it on a loaded
machine, still far above the bound). Prints one line; exit 1 on failure.
"""
from __future__ import annotations

import os
import pty
import re
import select
import signal
import subprocess
import sys
import time

WINDOW_S = 1.0          #: how long the CPU time is measured
MAX_CPU_S = 0.15        #: an idle master on a pty uses ~0 s of it
FIRST_FRAME_S = 10.0    #: bound on the wait for the example's first bytes on the line


def fail(msg: str) -> None:
    print(f"FAIL: {msg}")
    sys.exit(1)


def example_source(roff: str) -> str:
    m = re.search(r"^\.SH EXAMPLE\n\.nf\n(.*?)^\.fi$", roff, re.S | re.M)
    if not m:
        fail("the page has no EXAMPLE block")
    lines = [ln[2:] if ln.startswith("\\&") else ln for ln in m.group(1).splitlines()]
    return "\n".join(lines).replace("\\e", "\\") + "\n"


def synopsis_dirs(roff: str) -> tuple[str, str]:
    m = re.search(r"^cc -I(\S+) app\.c -L(\S+) -lfap -lpthread -lrt$", roff.replace("\\-", "-"), re.M)
    if not m:
        fail("the SYNOPSIS has no 'cc -I<dir> app.c -L<dir> -lfap -lpthread -lrt' line")
    return m.group(1), m.group(2)


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def sanitizer_flags(so: str) -> list:
    """A libfap built with -Db_sanitize (CI's ASan and TSan builds) needs its
    program built with the same runtime first in line: the flags that match
    the runtimes the library links (the vendor compile line otherwise)."""
    with open(os.path.realpath(so), "rb") as f:
        blob = f.read()
    if b"libtsan.so" in blob:
        return ["-fsanitize=thread"]
    return ["-fsanitize=" + ",".join(name for name, lib in (("address", b"libasan.so"),
                                                            ("undefined", b"libubsan.so"))
                                     if lib in blob)] if b"libasan.so" in blob else []


def main(page: str, dest: str, work: str) -> None:
    roff = open(page, encoding="utf-8").read()
    incdir, libdir = synopsis_dirs(roff)
    inc, lib = dest + incdir, dest + libdir
    if not os.path.isfile(os.path.join(inc, "fap.h")):
        fail(f"the SYNOPSIS names -I{incdir}, but the install has no {incdir}/fap.h")
    if not os.path.exists(os.path.join(lib, "libfap.so")):
        fail(f"the SYNOPSIS names -L{libdir}, but the install has no {libdir}/libfap.so")
    src, exe = os.path.join(work, "example.c"), os.path.join(work, "example")
    with open(src, "w", encoding="utf-8") as f:
        f.write(example_source(roff))
    cc = os.environ.get("CC", "cc").split() + sanitizer_flags(os.path.join(lib, "libfap.so"))
    r = subprocess.run(cc + ["-Wall", "-Wextra", "-Werror", f"-I{inc}", src, "-o", exe,
                             f"-L{lib}", "-lfap", "-lpthread", "-lrt"],
                       capture_output=True, text=True, timeout=120)
    if r.returncode:
        fail(f"the EXAMPLE does not compile with its SYNOPSIS line:\n{r.stderr[-2000:]}")
    far, near = pty.openpty()
    path = os.ttyname(near)
    env = dict(os.environ, LD_LIBRARY_PATH=lib)
    proc = subprocess.Popen([exe, path], env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    # near stays open: with no slave side open, the master side reads EIO
    try:
        ready, _, _ = select.select([far], [], [], FIRST_FRAME_S)
        if not ready or proc.poll() is not None:
            err = proc.stderr.read().decode(errors="replace") if proc.poll() is not None else ""
            fail(f"the example did not start on {path} (exit {proc.poll()}): {err.strip()}")
        os.read(far, 4096)
        before = cpu_seconds(proc.pid)
        time.sleep(WINDOW_S)               # the measurement window, not a synchronisation
        used = cpu_seconds(proc.pid) - before
        if proc.poll() is not None:
            fail(f"the example exited ({proc.returncode}) while it should wait for frames")
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        os.close(far)
        os.close(near)
    if used >= MAX_CPU_S:
        fail(f"{os.path.basename(page)}'s example spins: {used:.2f} s of CPU in {WINDOW_S} s "
             f"waiting for a frame (bound {MAX_CPU_S} s)")
    print(f"ok: {os.path.basename(page)}'s example compiled with -I{incdir} -L{libdir}, "
          f"{used:.3f} s of CPU in {WINDOW_S} s of waiting")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(*sys.argv[1:])
