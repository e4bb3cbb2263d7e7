#!/usr/bin/env bash
# The x86 direction-control suite on real 8250 and ftdi_sio drivers:
# Debian's amd64 kernel in qemu-system-x86_64 (q35, TCG), ISA 16550A
# ttyS0/ttyS1, a PCI 16550 (ttyS2) and an FTDI adapter on xHCI (ttyUSB0),
# each wired to a host pty; libfap and the check programs built statically
# with the host gcc. See docs/port.md ("Direction control on real drivers").
#   tests/qemu/x86/run.sh
# Env: FAP_QEMU_CACHE (downloads and builds; default <repo>/build/qemu-x86),
#      LIBFAP_SRC (the tree whose csrc/ is tested; default this repository),
#      FAP_QEMU_ACCEL (tcg, the default: the nested KVM here hangs the guest).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../../.." && pwd)
src=${LIBFAP_SRC:-$repo}
cache=${FAP_QEMU_CACHE:-$repo/build/qemu-x86}
export DEBIAN_FRONTEND=noninteractive
t0=$(date +%s.%N)

need=()
command -v qemu-system-x86_64 >/dev/null || need+=(qemu-system-x86)
command -v cc >/dev/null || need+=(gcc)
[ -e /usr/lib/x86_64-linux-gnu/libc.a ] || need+=(libc6-dev)
if [ ${#need[@]} -gt 0 ]; then
  apt-get update -q
  apt-get install -y -q -o DPkg::Lock::Timeout=600 "${need[@]}"
fi

# Debian's amd64 kernel and busybox (downloaded once, cached).
mkdir -p "$cache/deb"
kpkg=$(apt-cache depends linux-image-amd64 | awk '/Depends: linux-image-[0-9]/{print $2; exit}')
if [ -z "$kpkg" ]; then apt-get update -q; kpkg=$(apt-cache depends linux-image-amd64 | awk '/Depends: linux-image-[0-9]/{print $2; exit}'); fi
kver=${kpkg#linux-image-}
if ! ls "$cache"/deb/linux-image-"$kver"_*.deb >/dev/null 2>&1 || ! ls "$cache"/deb/busybox-static_*.deb >/dev/null 2>&1; then
  (cd "$cache/deb" && apt-get download "$kpkg" busybox-static 2>&1 | grep -v '^W: Download is performed unsandboxed' || true)
fi
if [ ! -e "$cache/k/boot/vmlinuz-$kver" ]; then
  rm -rf "$cache/k" && mkdir -p "$cache/k"
  dpkg-deb -x "$cache"/deb/linux-image-"$kver"_*.deb "$cache/k"
fi
if [ ! -e "$cache/bb/bin/busybox" ]; then
  rm -rf "$cache/bb" && mkdir -p "$cache/bb"
  dpkg-deb -x "$(ls "$cache"/deb/busybox-static_*.deb | head -1)" "$cache/bb"
fi

# libfap (the tree under test) and the programs, static, host gcc.
root=$cache/root obj=$cache/obj
rm -rf "$root" "$obj" && mkdir -p "$root" "$obj/gen/common"
printf '#define LF_VERSION "qemu-x86-suite"\n' > "$obj/gen/common/version_config.h"
cflags=(-O1 -g0 -std=gnu11 -D_GNU_SOURCE -Wall -Wextra -Werror -I"$src/include" -I"$src/csrc" -I"$obj/gen")
find "$src/csrc" -name '*.c' | sort | xargs -P "$(nproc)" -I{} sh -c \
  'obj=$1 src=$2; shift 2; exec cc "$@" -c "$src" -o "$obj/$(echo "$src" | md5sum | cut -c1-12).o"' \
  sh "$obj" {} "${cflags[@]}"
ar rcs "$obj/libfap.a" "$obj"/*.o
link() { cc "${cflags[@]}" -static "$@" "$obj/libfap.a" -lpthread -lrt -lm; }
link -o "$root/x86_checks" "$here/x86_checks.c"
link -o "$root/fap_master" "$src/examples/fap/fap_master.c"
link -o "$cache/fap_slave_host" "$src/examples/fap/fap_slave.c"
cp "$cache/bb/bin/busybox" "$root/busybox"
for m in virtio_ring virtio virtio_pci_modern_dev virtio_pci_legacy_dev virtio_pci \
         virtio_console usb-common usbcore xhci-hcd xhci-pci usbserial ftdi_sio; do
  ko=$(find "$cache/k/lib/modules" -name "$m.ko" | head -1)
  [ -n "$ko" ] || { echo "qemu x86 suite: module $m.ko not in $kpkg" >&2; exit 1; }
  cp "$ko" "$root/"
done
cp "$here/init.sh" "$root/init"
t1=$(date +%s.%N)
python3 -c "print('qemu x86 suite: prerequisites and builds %.1f s' % ($t1 - $t0))"

python3 "$here/run.py" --kernel "$cache/k/boot/vmlinuz-$kver" --root "$root" \
  --work "$cache/run" --slave "$cache/fap_slave_host" --accel "${FAP_QEMU_ACCEL:-tcg}"
