#!/usr/bin/env bash
# CI: a machine without the optional peers. Every target (not only what the
# tests need) builds with -Werror when pkg-config finds nothing and every
# meson feature is off; then the README's two Quickstart commands, taken
# from README.md, pass in a fresh copy of the tree with the C peer
# (libmodbus) hidden and no Python peer (pymodbus, minimalmodbus,
# dynamixel-sdk) in the venv.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
export DEBIAN_FRONTEND=noninteractive
need=()
command -v cc >/dev/null || need+=(gcc)
command -v pkg-config >/dev/null || need+=(pkg-config)
command -v git >/dev/null || need+=(git)
python3 -c 'import venv, ensurepip' 2>/dev/null || need+=(python3-venv)
if [ ${#need[@]} -gt 0 ]; then
  apt-get update -q && apt-get install -y -q "${need[@]}"
fi
[ -x .venv/bin/meson ] || { python3 -m venv .venv && .venv/bin/pip install -q 'meson>=1.1' ninja; }

empty=$(mktemp -d)           # an empty pkg-config search path: no peer is found
trap 'rm -rf "$empty"' EXIT

# 1. Every target, peers hidden two ways at once, -Werror.
rm -rf build-nopeers
PKG_CONFIG_LIBDIR=$empty PKG_CONFIG_PATH= .venv/bin/meson setup build-nopeers \
  --werror --auto-features=disabled -Dpython=false -Dpytest=false >/dev/null
if grep -q '^Run-time dependency libmodbus found: YES' build-nopeers/meson-logs/meson-log.txt; then
  echo "nopeers: libmodbus was found although hidden" >&2; exit 1
fi
.venv/bin/meson compile -C build-nopeers
echo "nopeers: every target built with -Werror, no peer"

# 2. The README's Quickstart commands, verbatim, in a fresh copy of the tree.
fresh=build-nopeers/fresh
mkdir -p "$fresh"
git ls-files -co --exclude-standard -z | xargs -0 tar -cf - | tar -xf - -C "$fresh"
mapfile -t cmds < <(python3 - README.md <<'PY'
import re, sys
text = open(sys.argv[1]).read()
quick = text.split("## Quickstart", 1)[1].split("\n## ", 1)[0]
for block in re.findall(r"```sh\n(.*?)```", quick, re.S):
    print(block.strip())
PY
)
[ ${#cmds[@]} -eq 2 ] || { echo "nopeers: expected 2 Quickstart commands in README.md, found ${#cmds[@]}" >&2; exit 1; }
for c in "${cmds[@]}"; do
  echo "nopeers: running (peers hidden): $c"
  (cd "$fresh" && env -u VIRTUAL_ENV PKG_CONFIG_LIBDIR="$empty" PKG_CONFIG_PATH= bash -euo pipefail -c "$c")
done
for mod in pymodbus minimalmodbus dynamixel_sdk; do
  if "$fresh/.venv/bin/python" -c "import $mod" 2>/dev/null; then
    echo "nopeers: Python peer $mod is installed in the fresh venv; it must not be needed" >&2; exit 1
  fi
done
if grep -q '^Run-time dependency libmodbus found: YES' "$fresh/build/meson-logs/meson-log.txt"; then
  echo "nopeers: the README build found libmodbus although hidden" >&2; exit 1
fi
echo "nopeers: OK (all targets -Werror without peers; both README commands pass without peers)"
