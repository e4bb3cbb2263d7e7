#!/usr/bin/env bash
# Build the libFuzzer targets with clang: -fsanitize=fuzzer,address,undefined.
# The library sources are compiled once (fuzzer-no-link) into a static
# archive, then each fuzz_*.c links against it.
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
san="-fsanitize=address,undefined -fno-sanitize-recover=undefined"
flags="-g -O1 -std=gnu11 -D_GNU_SOURCE -Wall -Wextra -Werror -I$root/include -I$root/csrc -I$out"
# version.c needs meson's generated header; the targets do not use it.
srcs=$(ls "$root"/csrc/common/*.c "$root"/csrc/fap/*.c "$root"/csrc/execasync/*.c \
          "$root"/csrc/mikroc/*.c "$root"/csrc/port/*.c | grep -v '/version\.c$')
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
for t in "$root"/tests/fuzz/fuzz_*.c; do
  name="$(basename "${t%.c}")"
  $CC $flags $san -fsanitize=fuzzer "$t" "$out/libfap_fuzz.a" -lpthread -lrt -lm -o "$out/$name"
done
echo "fuzz: built $(ls "$root"/tests/fuzz/fuzz_*.c | wc -l) targets in $out"
