#!/usr/bin/env bash
# CI: the kernel RS-485 suite on a real UART driver (PL011 in
# qemu-system-aarch64, Debian's arm64 kernel). tests/qemu/run.sh installs
# its own prerequisites (qemu-system-arm, gcc-aarch64-linux-gnu,
# libc6-dev-arm64-cross, arm64 kernel + busybox-static via apt-get download).
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)
bash tests/qemu/run.sh
echo "qemu: OK (PL011 kernel RS-485 suite passed in $(( $(date +%s) - start )) s)"
bash .ci/qemu_x86.sh   # the 8250 / ftdi_sio direction suite (tests/qemu/x86)
