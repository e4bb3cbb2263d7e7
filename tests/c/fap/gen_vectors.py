"""Turn tests/c/fap/vectors/fap.json into a C header for the codec tests.

Run by meson at build time: python3 gen_vectors.py fap.json out.h
"""
import json
import sys


def c_bytes(hexstr: str) -> str:
    b = bytes.fromhex(hexstr)
    if not b:
        return '(const uint8_t *)""', 0
    return '(const uint8_t *)"' + "".join(f"\\x{x:02x}" for x in b) + '"', len(b)


def main() -> None:
    vec = json.load(open(sys.argv[1], encoding="utf-8"))
    out = ["/* generated from vectors/fap.json by gen_vectors.py */",
           "#include <stddef.h>", "#include <stdint.h>",
           "typedef struct { const char *name; int msg, dst, src; const uint8_t *data; size_t len;",
           "                 const uint8_t *frame; size_t frame_len; const char *reason; } fapvec;"]

    def entry(v):
        d, dl = c_bytes(v.get("data", ""))
        f, fl = c_bytes(v["frame"])
        name = json.dumps(v.get("name", "alt"))
        reason = json.dumps(v.get("reason", ""))
        return (f"  {{ {name}, {v.get('msg', -1)}, {v.get('dst', -1)}, {v.get('src', -1)}, "
                f"{d}, {dl}, {f}, {fl}, {reason} }},")

    for key in ("valid", "invalid"):
        out.append(f"static const fapvec fapvec_{key}[] = {{")
        out += [entry(v) for v in vec[key]]
        out.append("};")
    out.append("static const fapvec fapvec_alt = " + entry(vec["alternate_marker_frame"])[2:-1] + ";")
    s, sl = c_bytes(vec["stream"]["bytes"])
    out.append(f"static const uint8_t *const fapvec_stream = {s};")
    out.append(f"static const size_t fapvec_stream_len = {sl};")
    out.append(f"static const unsigned fapvec_stream_crc_errors = {vec['stream']['crc_errors']};")
    out.append("static const fapvec fapvec_stream_frames[] = {")
    for fr in vec["stream"]["frames"]:
        d, dl = c_bytes(fr["data"])
        out.append(f"  {{ \"stream\", {fr['msg']}, {fr['dst']}, {fr['src']}, {d}, {dl}, 0, 0, \"\" }},")
    out.append("};")
    open(sys.argv[2], "w", encoding="utf-8").write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
