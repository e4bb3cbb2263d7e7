/* fap_codec.h - the receivers' sans-I/O decoders behind one table.
 *
 * One const table per protocol (libmodbus's backend table), each decoding
 * with llhttp's shape: feed bytes and the time they arrived, and the codec
 * calls back with every good frame and every run of bytes it dropped.
 * There is no second decoder here: each entry wraps the scanner its
 * engine uses (csrc/fap/codec.c, execAsyncByteIn, the mikroC
 * decoder), so a monitor, a fuzzer or a test sees exactly what a receiver
 * sees. The engines still call their scanners directly (no indirection
 * on their hot path). docs/c-api.md, "Codec table", has the rules.
 *
 * Usage:
 *     const fap_codec *c = fap_codec_find("exec");
 *     void *st = malloc(c->state_size);
 *     c->init(st, 115200, 0);
 *     c->feed(st, bytes, n, now_ns, on_frame, on_reject, ctx);
 *     ...  when the line is quiet (c->deadline(st) passed): c->tick(...)
 *     c->finish(st, on_frame, on_reject, ctx);   at the end of the input
 *
 * Reports come in stream order, each with the stream offset of its first
 * byte (bytes fed before it). For exec and mikroc the reports tile the
 * stream: every byte is in exactly one report. FAP rejects a candidate
 * frame by its first byte only and scans the rest again, so its later
 * bytes may be reported again (as garbage, another candidate or inside a
 * good frame). Every function is reentrant on distinct states; one state
 * is used by one thread at a time. The callbacks' pointers are valid
 * during the call only. */
#ifndef FAP_CODEC_H
#define FAP_CODEC_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Reject codes every codec shares; the others are the codec's own
 * (reject_name() names them all). */
#define FAP_CODEC_GARBAGE    1      /* bytes that start no frame */
#define FAP_CODEC_TRUNCATED  64     /* a partial frame at the end of the input */
#define FAP_CODEC_MAX_FIELDS 4      /* header fields of a frame, at most */
#define FAP_CODEC_NEVER      INT64_MAX  /* a deadline that never comes */

/* A good frame. field[i] is the header field named field_names[i] of its
 * codec (FAP: msg, dst, src; exec: node, seq; mikroc: address,
 * from_master). */
typedef struct fap_codec_frame {
    uint64_t offset;            /* stream offset of raw[0] */
    const uint8_t *raw;         /* the frame as it was on the wire */
    size_t raw_len;
    const uint8_t *data;        /* its payload, unstuffed/unescaped */
    size_t data_len;
    unsigned field[FAP_CODEC_MAX_FIELDS];
} fap_codec_frame;

typedef void (*fap_codec_frame_cb)(void *ctx, const fap_codec_frame *f);
/* Dropped bytes: code is FAP_CODEC_GARBAGE, FAP_CODEC_TRUNCATED or the
 * codec's reason; raw/n the bytes, offset the stream offset of raw[0]. */
typedef void (*fap_codec_reject_cb)(void *ctx, int code, const uint8_t *raw, size_t n,
                                    uint64_t offset);

typedef struct fap_codec {
    const char *name;               /* "fap", "exec", "mikroc" */
    size_t state_size;              /* bytes of the caller-allocated state */
    unsigned n_fields;              /* entries of field_names */
    const char *const *field_names;
    /* Start a stream. baud (0 unknown) and gap_ns (0: from the baud) set
     * the inter-byte gap where the receiver has one (FAP). */
    void (*init)(void *state, unsigned baud, int64_t gap_ns);
    /* n bytes that arrived at now_ns (CLOCK_MONOTONIC). Reports what they
     * complete; a partial frame is held. Either callback may be NULL. */
    void (*feed)(void *state, const uint8_t *p, size_t n, int64_t now_ns,
                 fap_codec_frame_cb on_frame, fap_codec_reject_cb on_reject, void *ctx);
    /* When tick() would abandon the held partial frame (FAP_CODEC_NEVER:
     * nothing held, or the receiver has no gap rule). */
    int64_t (*deadline)(const void *state);
    /* The line is quiet at now_ns: apply the inter-byte gap, and report
     * bytes already known to start no frame. */
    void (*tick)(void *state, int64_t now_ns, fap_codec_frame_cb on_frame,
                 fap_codec_reject_cb on_reject, void *ctx);
    /* End of the input: a held partial frame is FAP_CODEC_TRUNCATED, the
     * rest garbage (or frames FAP finds on rescanning). The state is then
     * ready for a new stream continuing the offsets. */
    void (*finish)(void *state, fap_codec_frame_cb on_frame,
                   fap_codec_reject_cb on_reject, void *ctx);
    /* Short name of a reject code ("garbage", "crc", ...; "?" unknown). */
    const char *(*reject_name)(int code);
    /* Name of a frame's message type (FAP's "SEND_DATA"...), NULL when
     * the protocol has none. */
    const char *(*frame_name)(const fap_codec_frame *f);
    /* A lower bound on the bytes still needed to end a frame, as the
     * engine paces its reads (FAP: 0 when nothing is held). */
    size_t (*missing)(const void *state);
    /* Encode one frame with header fields field[0..n_fields-1] and len
     * bytes of data into out (cap bytes; max_frame always fits). Returns
     * its length, or 0 when a field or len is out of range (nothing
     * useful written). */
    size_t (*encode)(uint8_t *out, size_t cap, const unsigned *field,
                     const uint8_t *data, size_t len);
    size_t max_frame;               /* the longest frame encode() writes */
} fap_codec;

/* The codec called name ("fap", "exec", "mikroc"; "execasync" is accepted
 * for exec), or NULL. */
const fap_codec *fap_codec_find(const char *name);
/* The i-th codec of the table (0, 1, ...), NULL past the last: iterate
 * with for (i = 0; (c = fap_codec_at(i)); i++). */
const fap_codec *fap_codec_at(size_t i);

#ifdef __cplusplus
}
#endif
#endif
