#!/usr/bin/env bash
# The kernel RS-485 suite on a real UART driver: Debian's arm64 kernel in
# qemu-system-aarch64 (virt, PL011 /dev/ttyAMA0 wired to a host pty),
# libfap and the check programs cross-built for aarch64, a FAP slave on
# the host end of the line. See docs/port.md ("Evidence").
#   tests/qemu/run.sh                  # from the repository root or anywhere
# Env: FAP_QEMU_CACHE (downloads and builds; default <repo>/build/qemu),
#      LIBFAP_SRC (the tree whose csrc/ is tested; default this repository).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../.." && pwd)
src=${LIBFAP_SRC:-$repo}
cache=${FAP_QEMU_CACHE:-$repo/build/qemu}
export DEBIAN_FRONTEND=noninteractive
t0=$(date +%s.%N)

# Prerequisites (Debian): the emulator, the cross compiler, arm64 packages.
need=()
command -v qemu-system-aarch64 >/dev/null || need+=(qemu-system-arm)
command -v aarch64-linux-gnu-gcc >/dev/null || need+=(gcc-aarch64-linux-gnu)
[ -e /usr/aarch64-linux-gnu/lib/libc.a ] || need+=(libc6-dev-arm64-cross)
command -v cc >/dev/null || need+=(gcc)
if ! dpkg --print-foreign-architectures | grep -qx arm64; then
  dpkg --add-architecture arm64
  apt-get update -q
fi
if [ ${#need[@]} -gt 0 ]; then
  apt-get install -y -q -o DPkg::Lock::Timeout=600 "${need[@]}"
fi

# Debian's arm64 kernel and busybox (downloaded once, cached).
mkdir -p "$cache/deb" "$cache/root"
kpkg=$(apt-cache depends linux-image-arm64:arm64 | awk '/Depends: linux-image-[0-9]/{print $2; exit}')
if [ -z "$kpkg" ]; then apt-get update -q; kpkg=$(apt-cache depends linux-image-arm64:arm64 | awk '/Depends: linux-image-[0-9]/{print $2; exit}'); fi
kver=${kpkg#linux-image-}; kver=${kver%:arm64}
if ! ls "$cache"/deb/linux-image-"$kver"_*.deb >/dev/null 2>&1 || ! ls "$cache"/deb/busybox-static_*.deb >/dev/null 2>&1; then
  (cd "$cache/deb" && apt-get download "$kpkg" busybox-static:arm64 2>&1 | grep -v '^W: Download is performed unsandboxed' || true)
fi
if [ ! -e "$cache/k/boot/vmlinuz-$kver" ]; then
  rm -rf "$cache/k" && mkdir -p "$cache/k"
  dpkg-deb -x "$cache"/deb/linux-image-"$kver"_*.deb "$cache/k"
fi
if [ ! -e "$cache/bb/bin/busybox" ]; then
  rm -rf "$cache/bb" && mkdir -p "$cache/bb"
  dpkg-deb -x "$cache"/deb/busybox-static_*.deb "$cache/bb"
fi

# libfap (the tree under test) cross-built, statically linked programs.
root=$cache/root
rm -rf "$root" "$root.obj" && mkdir -p "$root/gen/common"
printf '#define LF_VERSION "qemu-suite"\n' > "$root/gen/common/version_config.h"
mapfile -t libsrc < <(find "$src/csrc" -name '*.c' | sort)
cflags=(-O1 -g0 -std=gnu11 -D_GNU_SOURCE -Wall -Wextra -Werror -I"$src/include" -I"$src/csrc" -I"$root/gen")
# Each library source compiled once per architecture into an archive.
build_lib() {   # build_lib CC OUTDIR
  local cc=$1 out=$2; mkdir -p "$out"
  printf '%s\n' "${libsrc[@]}" | xargs -P "$(nproc)" -I{} sh -c \
    'out=$1 src=$2 cc=$3; shift 3; exec "$cc" "$@" -c "$src" -o "$out/$(echo "$src" | md5sum | cut -c1-12).o"' \
    sh "$out" {} "$cc" "${cflags[@]}"
  ar rcs "$out/libfap.a" "$out"/*.o
}
build_lib aarch64-linux-gnu-gcc "$root.obj/aarch64"
build_lib cc "$root.obj/host"
xlink() { aarch64-linux-gnu-gcc "${cflags[@]}" -static "$@" "$root.obj/aarch64/libfap.a" -lpthread -lrt -lm; }
xlink -o "$root/rs485_checks" "$here/rs485_checks.c"
xlink -o "$root/classic_noclose" "$here/classic_noclose.c"
xlink -o "$root/fap_master" "$src/examples/fap/fap_master.c"
cc "${cflags[@]}" -o "$cache/fap_slave_host" "$src/examples/fap/fap_slave.c" "$root.obj/host/libfap.a" -lpthread -lrt -lm
cp "$cache/bb/bin/busybox" "$root/busybox"
cp "$(find "$cache/k" -name virtio_mmio.ko)" "$(find "$cache/k" -name virtio_console.ko)" "$root/"
cp "$here/init.sh" "$root/init"
t1=$(date +%s.%N)
python3 -c "print('qemu suite: prerequisites and builds %.1f s' % ($t1 - $t0))"

python3 "$here/run.py" --kernel "$cache/k/boot/vmlinuz-$kver" --root "$root" \
  --work "$cache/run" --slave "$cache/fap_slave_host"
