#!/bin/sh
# Install libfap (headers, libraries, fap.pc) into a scratch DESTDIR and
# build a vendor-style program against it, both with the plain
# `cc -I<includedir>/libfap app.c -lfap -lpthread -lrt` and with pkg-config;
# then each example directory copied alone out of the tree, its makefile
# both through pkg-config and through PREFIX.
set -eu
builddir=$1; srcdir=$2; examples=${3:-}
cc=${CC:-cc}
dest=$(mktemp -d)
trap 'rm -rf "$dest"' EXIT
meson install -C "$builddir" --destdir "$dest" --tags devel,runtime --quiet >/dev/null
libso=$(find "$dest" -name 'libfap.so' | head -n 1)
hdr=$(find "$dest" -name 'fap.h' | head -n 1)
pc=$(find "$dest" -name 'fap.pc' | head -n 1)
[ -n "$libso" ] && [ -n "$hdr" ] && [ -n "$pc" ] || { echo "missing installed files"; exit 1; }
find "$dest" -name 'libfap.a' | grep -q . || { echo "libfap.a not installed"; exit 1; }
libdir=$(dirname "$libso"); incdir=$(dirname "$hdr")
# headers in their own directory, never in the root of include/ (the APRS
# parser also called libfap installs a fap.h there)
[ "$(basename "$incdir")" = libfap ] || { echo "fap.h installed in $incdir, not include/libfap"; exit 1; }
prefix=$(dirname "$(dirname "$incdir")")   # DESTDIR + the configured prefix

# 1. the vendor's way: -I to the header directory, the library by name
$cc -I"$incdir" "$srcdir/vendor_app.c" -o "$dest/app_plain" -L"$libdir" -lfap -lpthread -lrt
LD_LIBRARY_PATH=$libdir "$dest/app_plain" /nonexistent/ttyFAP

# 2. pkg-config (the .pc names the final prefix; the sysroot maps it into DESTDIR)
export PKG_CONFIG_PATH="$(dirname "$pc")" PKG_CONFIG_SYSROOT_DIR="$dest"
cflags=$(pkg-config --cflags fap)
case " $cflags " in
  *" -I$incdir "*) ;;
  *) echo "pkg-config --cflags fap gave '$cflags', not -I$incdir"; exit 1 ;;
esac
$cc "$srcdir/vendor_app.c" -o "$dest/app_pc" $cflags $(pkg-config --libs fap)
LD_LIBRARY_PATH=$libdir "$dest/app_pc" /nonexistent/ttyFAP
passed=2

# 3. the example makefiles, each directory copied ALONE out of the tree (as a
#    user starts a project from it: nothing outside it may be needed), built
#    through pkg-config, then through PREFIX alone (meson's libdir, e.g.
#    lib/x86_64-linux-gnu, found without LIBDIR)
if [ -n "$examples" ]; then
  command -v make >/dev/null || { echo "make missing"; exit 1; }
  for mk in "$examples"/*/Makefile; do   # every example folder with a makefile
    ex=$(basename "$(dirname "$mk")")
    for way in pc prefix; do
      mkdir -p "$dest/ex-$way"
      cp -R "$examples/$ex" "$dest/ex-$way/$ex"
      rm -f "$dest/ex-$way/$ex/meson.build"    # the in-tree build's file, not the makefile's
    done
    make -s -C "$dest/ex-pc/$ex" CC="$cc" \
      || { echo "examples/$ex copied alone: make (pkg-config) failed"; exit 1; }
    env -u PKG_CONFIG_PATH make -s -C "$dest/ex-prefix/$ex" CC="$cc" PREFIX="$prefix" \
      || { echo "examples/$ex copied alone: make PREFIX=... failed"; exit 1; }
  done
  # the block that finds libfap is the same in every makefile (one convention)
  block() { sed -n '/^# ---- finding libfap/,/^# -----------*$/p' "$1"; }
  ref=$(block "$examples/fap/Makefile")
  [ -n "$ref" ] || { echo "examples/fap/Makefile: no libfap block"; exit 1; }
  for mk in "$examples"/*/Makefile; do
    ex=$(basename "$(dirname "$mk")")
    [ "$(block "$mk")" = "$ref" ] \
      || { echo "examples/$ex/Makefile: its libfap block differs from examples/fap's"; exit 1; }
  done
  # each runs and reaches fapInit / its open (the PREFIX build through its rpath alone)
  for way in pc prefix; do
    ld=$([ $way = pc ] && echo "$libdir" || true)
    out=$(LD_LIBRARY_PATH=$ld "$dest/ex-$way/fap/fap_slave" /nonexistent/ttyFAP 7 2>&1) || true
    case $out in *"fapInit() Failed"*) ;; *) echo "ex-$way fap_slave: $out"; exit 1 ;; esac
    for mk in "$examples"/*/Makefile; do   # every program its makefile's `all:` names
      ex=$(basename "$(dirname "$mk")")
      for bin in $(sed -n 's/^all:[[:space:]]*//p' "$mk"); do
        [ -x "$dest/ex-$way/$ex/$bin" ] || { echo "ex-$way: $ex/$bin not built"; exit 1; }
      done
    done
  done
  passed=5
fi
echo "$passed passed, 0 failed"
