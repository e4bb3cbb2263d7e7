#!/bin/sh
# The man pages: mandoc -Tlint finds nothing at any level (style included);
# `meson install --tags man` puts them where `man -M PREFIX/share/man` finds
# fapInit(3), fapx_open(3), libfap(7), fap(1) and fap-monitor(1); every
# header function has its man3 page; every man3 page and libfap(7) name the
# install's own header and library directories (not a fixed /usr/local);
# fapInit(3)'s EXAMPLE, compiled with its SYNOPSIS line, waits for frames
# without spinning (run_man_example.py). Skipped (77) without mandoc or man
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
meson install -C "$builddir" --destdir "$dest" --tags man,devel,runtime --no-rebuild --quiet >/dev/null
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

# 4. the compile line names this install's directories: where fap.h and
#    libfap.so really are under the prefix (whatever --prefix/--libdir said)
hdr=$(find "$dest" -name fap.h -path '*/libfap/*' | head -n 1)
lib=$(find "$dest" -name libfap.so | head -n 1)
[ -n "$hdr" ] && [ -n "$lib" ] || { echo "fap.h or libfap.so not installed"; exit 1; }
incdir=$(dirname "${hdr#"$dest"}"); libdir=$(dirname "${lib#"$dest"}")
check 3 fapInit "cc -I$incdir app.c -L$libdir -lfap -lpthread -lrt"
check 3 fap_port_open "cc -I$incdir app.c -L$libdir -lfap -lpthread -lrt"
check 7 libfap "-I$incdir app.c -L$libdir -lfap"
wrong=$(grep -L -F -e "cc \\-I$incdir app.c \\-L$libdir \\-lfap \\-lpthread \\-lrt" "$mandir"/man3/*) || true
[ -z "$wrong" ] || { echo "man3 pages without the install's -I$incdir/-L$libdir:"; echo "$wrong" | head; exit 1; }
passed=$((passed + 1))

# 5. fapInit(3)'s EXAMPLE, compiled from the installed page with its own
#    SYNOPSIS line, runs on a pty and waits for a frame without spinning
work=$(mktemp -d)
trap 'rm -rf "$dest" "$work"' EXIT
python3 "$srcdir/tests/man/run_man_example.py" "$mandir/man3/fapInit.3" "$dest" "$work"
passed=$((passed + 1))
echo "$passed passed, 0 failed"
