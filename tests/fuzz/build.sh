#!/usr/bin/env bash
# Build the libFuzzer targets with clang: -fsanitize=fuzzer,address,undefined.
# The library sources of every component of meson.build's `components` list
# are compiled once (fuzzer-no-link) into a static archive, with the codec
# table's rows generated from that list as csrc/meson.build does; then each
# tests/fuzz/fuzz_*.c (found, not listed) links against it.
#   tests/fuzz/build.sh [OUT_DIR]      (default: build-fuzz)
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
out="${1:-$root/build-fuzz}"
CC="${CC:-}"
if [ -z "$CC" ]; then
  for c in clang clang-14 clang-15 clang-16; do
    command -v "$c" >/dev/null && { CC="$c"; break; }
  done
fi
[ -n "$CC" ] || { echo "fuzz: error: clang not found (apt-get install clang libclang-rt-14-dev)" >&2; exit 3; }
mkdir -p "$out/obj"
# the components, as meson.build lists them (the one list)
components=$(python3 - "$root/meson.build" <<'PY'
import re, sys
m = re.search(r"^components\s*=\s*\[([^\]]*)\]", open(sys.argv[1]).read(), re.M)
print(" ".join(re.findall(r"'([^']+)'", m.group(1))) if m else "")
PY
)
[ -n "$components" ] || { echo "fuzz: error: no components list in meson.build" >&2; exit 3; }
# the codec table's rows: every component but common with a codec_table.c
rows=""
for c in $components; do
  [ "$c" != common ] && [ -e "$root/csrc/$c/codec_table.c" ] && rows="$rows LF_ROW($c)"
done
mkdir -p "$out/gen"
sed "s/@ROWS@/${rows# }/" "$root/csrc/codec_rows.c.in" > "$out/gen/codec_rows.c.new"
cmp -s "$out/gen/codec_rows.c.new" "$out/gen/codec_rows.c" 2>/dev/null \
  && rm "$out/gen/codec_rows.c.new" || mv "$out/gen/codec_rows.c.new" "$out/gen/codec_rows.c"
san="-fsanitize=address,undefined -fno-sanitize-recover=undefined"
flags="-g -O1 -std=gnu11 -D_GNU_SOURCE -Wall -Wextra -Werror -I$root/include -I$root/csrc -I$out"
# version.c needs meson's generated header; the targets do not use it.
srcs=""
for c in $components; do
  srcs="$srcs $(ls "$root"/csrc/"$c"/*.c | grep -v '/version\.c$')"
done
srcs="$srcs $out/gen/codec_rows.c"
objs=()
for s in $srcs; do
  o="$out/obj/$(basename "$(dirname "$s")")_$(basename "${s%.c}").o"
  if [ ! -e "$o" ] || [ "$s" -nt "$o" ] || [ "$0" -nt "$o" ]; then
    $CC $flags $san -fsanitize=fuzzer-no-link -c "$s" -o "$o"
  fi
  objs+=("$o")
done
rm -f "$out/libfap_fuzz.a"
ar rcs "$out/libfap_fuzz.a" "${objs[@]}"
n=0
for t in "$root"/tests/fuzz/fuzz_*.c; do
  name="$(basename "${t%.c}")"
  $CC $flags $san -fsanitize=fuzzer "$t" "$out/libfap_fuzz.a" -lpthread -lrt -lm -o "$out/$name"
  n=$((n + 1))
done
echo "fuzz: built $n targets in $out"
