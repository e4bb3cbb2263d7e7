#!/usr/bin/env bash
# CI: fap_py installs and runs without a compiler, from its wheels
# (docs/packaging.md). Builds the sdist and, from it, the x86_64 abi3 wheel
# (tools/build_wheels.sh); in a fresh venv per interpreter, fetches the
# dependencies' wheels while online, then, offline, with CC=/bin/false:
#   pip install --only-binary :all: --no-index --find-links wheelhouse fap_py
# and `fap demo` (2 s) plus tests/install/wheel_smoke.py. Interpreters: the
# system python3 and the oldest and newest other CPython >= 3.9 found
# (pyenv): one abi3 wheel for all. aarch64: the same in a Debian 12 arm64 chroot under qemu-user
# when the chroot is cached (/var/cache/fap-wheels) or FAP_WHEELS_ARM64=1
# (tools/arm64_chroot.sh makes it, ~5 min); FAP_WHEELS_ARM64=0: x86_64 only.
# Measured: 380 s with the chroot cached, 689 s from a clean state, 53 s x86_64 only.
set -euo pipefail
cd "$(dirname "$0")/.."
export DEBIAN_FRONTEND=noninteractive
need=()
command -v debootstrap >/dev/null || need+=(debootstrap)
[ -e /usr/lib/binfmt.d/qemu-aarch64.conf ] || need+=(qemu-user-static)
python3 -c 'import venv, ensurepip' 2>/dev/null || need+=(python3-venv)
if [ ${#need[@]} -gt 0 ]; then apt-get update -q && apt-get install -y -q "${need[@]}"; fi

start=$(date +%s)
wh=$(mktemp -d /tmp/fap-wheelhouse.XXXXXX)
arm_root=${FAP_ARM64_ROOT:-/var/cache/fap-wheels/bookworm-arm64}
arches=(x86_64)
case ${FAP_WHEELS_ARM64:-} in
  1) arches+=(aarch64) ;;                                   # makes the chroot if missing (~5 min)
  0) ;;                                                     # x86_64 only
  *) [ -f "$arm_root/.fap-ready" ] && arches+=(aarch64) ;;  # when the chroot is cached
esac
trap 'umount "$arm_root/dev/pts" "$arm_root/proc" 2>/dev/null || true; rm -rf "$wh"' EXIT

WHEELHOUSE=$wh bash tools/build_wheels.sh "${arches[@]}"

# The sdist builds: a wheel from it (tools/build_wheels.sh built the x86_64
# one from it) and, not from the git tree.
ls "$wh"/fap_py-*.tar.gz >/dev/null

# Interpreters: system python3, plus the oldest (>= 3.9) and the newest other
# CPython found (pyenv): the one abi3 wheel must serve them all.
pythons=(python3)
sysver=$(python3 -c 'import sys; print("%d.%02d" % sys.version_info[:2])')
others=$(for p in /root/.pyenv/versions/3.*/bin/python3 /usr/bin/python3.[0-9]*; do
  [ -x "$p" ] || continue
  v=$("$p" -c 'import sys; print("%d.%02d" % sys.version_info[:2])' 2>/dev/null) || continue
  [[ $v > 3.08 && $v != "$sysver" ]] && echo "$v $p"
done | sort -u -k1,1 | sed -n '1p;$p' | sort -u | cut -d' ' -f2)
for p in $others; do pythons+=("$p"); done

run_checks() {   # run_checks PYTHON: fresh venv, offline install with no compiler, demo, smoke
  local py=$1 venv
  venv=$(mktemp -d /tmp/fap-wheel-venv.XXXXXX)
  "$py" -m venv "$venv"
  # online: the dependencies' wheels for this interpreter (its own markers)
  "$venv/bin/pip" download -q --only-binary :all: -d "$wh" "$(ls "$wh"/fap_py-*_x86_64.whl)"
  # offline, no compiler
  CC=/bin/false "$venv/bin/pip" install -q --only-binary :all: --no-index --find-links "$wh" fap_py
  (cd /tmp && "$venv/bin/fap" demo --duration 2 --plain >/dev/null && "$venv/bin/python" "$OLDPWD/tests/install/wheel_smoke.py")
  rm -rf "$venv"
}

for py in "${pythons[@]}"; do
  run_checks "$py"
done

if [[ " ${arches[*]} " == *" aarch64 "* ]]; then
  # one interpreter there: Debian 12's python3 (3.11), under qemu-user
  rm -rf "$arm_root/tmp/fapci" && mkdir -p "$arm_root/tmp/fapci"
  cp -r "$wh" "$arm_root/tmp/fapci/wheelhouse"
  cp tests/install/wheel_smoke.py "$arm_root/tmp/fapci/"
  cp /etc/ssl/certs/ca-certificates.crt "$arm_root/etc/ssl/certs/host-ca-certificates.crt"
  cp /etc/resolv.conf "$arm_root/etc/resolv.conf"
  mountpoint -q "$arm_root/proc" || mount -t proc proc "$arm_root/proc"
  mountpoint -q "$arm_root/dev/pts" || mount -t devpts -o newinstance,ptmxmode=0666 devpts "$arm_root/dev/pts"
  env -i HOME=/root PATH=/usr/local/bin:/usr/bin:/bin:/usr/sbin:/sbin LANG=C.UTF-8 PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_CERT=/etc/ssl/certs/host-ca-certificates.crt chroot "$arm_root" /bin/sh -euc '
    cd /tmp/fapci
    python3 -m venv venv
    venv/bin/pip download -q --only-binary :all: -d wheelhouse wheelhouse/fap_py-*_aarch64.whl
    CC=/bin/false venv/bin/pip install -q --only-binary :all: --no-index --find-links wheelhouse fap_py
    echo "aarch64: $(uname -m), $(venv/bin/python -c "import platform; print(platform.machine())")"
    venv/bin/fap demo --duration 2 --plain >/dev/null
    venv/bin/python wheel_smoke.py'
  rm -rf "$arm_root/tmp/fapci"
fi
echo "wheels: ${arches[*]}, ${#pythons[@]} x86_64 interpreter(s), $(( $(date +%s) - start )) s"
