#!/bin/sh
# The man pages: mandoc -Tlint finds nothing at any level (style included);
# `meson install --tags man` puts them where `man -M PREFIX/share/man` finds
# fapInit(3), fapx_open(3), libfap(7), fap(1) and fap-monitor(1); every
# header function has its man3 page. Skipped (77) without mandoc or man
# unless CI is set.
set -eu
builddir=$1; srcdir=$2; shift 2   # then the public headers (man/meson.build: the components')
for tool in mandoc man; do
  if ! command -v $tool >/dev/null; then
    [ -n "${CI:-}" ] && { echo "$tool missing (CI)"; exit 1; }
    echo "SKIP: $tool missing"; exit 77
  fi
done
dest=$(mktemp -d)
trap 'rm -rf "$dest"' EXIT
# --no-rebuild: the pages are this test's dependencies (built); nothing else is needed
meson install -C "$builddir" --destdir "$dest" --tags man --no-rebuild --quiet >/dev/null
mandir=$(find "$dest" -type d -name man3 -path '*/share/man/*' | head -n 1)
mandir=${mandir%/man3}
[ -n "$mandir" ] || { echo "no man3 directory installed"; exit 1; }
passed=0

# 1. lint, style warnings included
lint=$(mandoc -Tlint -Wstyle "$mandir"/man*/* 2>&1) || true
[ -z "$lint" ] || { echo "mandoc -Tlint:"; echo "$lint" | head -20; exit 1; }
passed=$((passed + 1))

# 2. one man3 page per function declared in the public headers
n_pages=$(ls "$mandir/man3" | wc -l)
n_funcs=$(python3 "$srcdir/tools/gen_man3.py" --count "$@")
[ "$n_pages" -eq "$n_funcs" ] && [ "$n_funcs" -gt 100 ] || { echo "$n_pages man3 pages for $n_funcs functions"; exit 1; }
passed=$((passed + 1))

# 3. man finds and renders them from the installed prefix
check() {   # check SECTION PAGE TEXT: the rendered page contains TEXT
  out=$(MANWIDTH=100 MANPAGER=cat PAGER=cat man -M "$mandir" "$1" "$2" 2>&1) || { echo "man $1 $2: $out"; exit 1; }
  printf '%s\n' "$out" | grep -q -- "$3" || { echo "man $1 $2 lacks '$3':"; printf '%s\n' "$out" | head; exit 1; }
  passed=$((passed + 1))
}
check 3 fapInit "E_INIT"
check 3 fapx_open "fapx_options_init"
check 3 execMasterTransact "ETIMEDOUT"
check 3 mikrocRS485_Open "RS485Master_Init"
check 7 libfap "fap_port_open"
if [ -f "$mandir/man1/fap.1" ]; then
  check 1 fap "fap-monitor"
  check 1 fap-monitor "--protocol"
  check 1 fap-exec "FAP EXEC MASTER"
fi
echo "$passed passed, 0 failed"
