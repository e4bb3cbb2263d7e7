#!/usr/bin/env bash
# CI: the direction-control suite on the x86 8250 (ISA and PCI 16550) and
# ftdi_sio drivers in qemu-system-x86_64 (Debian's amd64 kernel, TCG).
# tests/qemu/x86/run.sh installs its own prerequisites (qemu-system-x86,
# gcc/libc6-dev; the amd64 kernel and busybox-static via apt-get download).
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)
bash tests/qemu/x86/run.sh
echo "qemu x86: OK (8250 + ftdi_sio direction suite passed in $(( $(date +%s) - start )) s)"
