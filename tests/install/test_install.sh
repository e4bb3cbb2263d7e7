#!/bin/sh
# Install libfap (headers, libraries, fap.pc) into a scratch DESTDIR and
# build a vendor-style program against it, both with the plain
# `cc app.c -lfap -lpthread -lrt` and with pkg-config.
set -eu
builddir=$1; srcdir=$2
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

# 1. the vendor's way: headers and library found through the usual search paths
C_INCLUDE_PATH=$incdir LIBRARY_PATH=$libdir \
  $cc "$srcdir/vendor_app.c" -o "$dest/app_plain" -lfap -lpthread -lrt
LD_LIBRARY_PATH=$libdir "$dest/app_plain" /nonexistent/ttyFAP

# 2. pkg-config (the .pc names the final prefix; the sysroot maps it into DESTDIR)
flags=$(PKG_CONFIG_PATH=$(dirname "$pc") PKG_CONFIG_SYSROOT_DIR=$dest pkg-config --cflags --libs fap)
$cc "$srcdir/vendor_app.c" -o "$dest/app_pc" $flags
LD_LIBRARY_PATH=$libdir "$dest/app_pc" /nonexistent/ttyFAP
echo "1 passed, 0 failed"
