/* fap_trace.h - wire trace hooks shared by every libfap protocol handle.
 *
 * A trace callback sees every frame a handle sends or receives, as raw
 * wire bytes, good or bad: FAP handles (fapx_set_trace), exec async
 * engines (execMasterSetTrace, execSlaveSetTrace) and mikroC contexts
 * (mikrocRS485_CtxSetTrace). docs/c-api.md has the rules; in short:
 *  - the callback runs on the thread that moves the bytes (the FAP engine
 *    thread; the thread inside an exec/mikroC call), never concurrently
 *    with itself for one handle;
 *  - the bytes are valid during the call only; copy what you keep;
 *  - it must return quickly and must not call back into the same handle
 *    (a FAP handle's engine would stall; setting the hook from inside it
 *    deadlocks). */
#ifndef FAP_TRACE_H
#define FAP_TRACE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum fap_trace_dir {
    FAP_TRACE_RX = 0,
    FAP_TRACE_TX = 1
} fap_trace_dir;

typedef enum fap_trace_status {
    FAP_TRACE_OK = 0,         /* a valid frame (tx: written completely) */
    FAP_TRACE_BAD_CRC = 1,    /* complete frame, checksum mismatch */
    FAP_TRACE_BAD_FRAME = 2,  /* bad header, length, escape or stop byte: the
                                 bytes up to where the frame failed */
    FAP_TRACE_TRUNCATED = 3,  /* partial frame abandoned: inter-byte gap, cut
                                 off by a new start, or too long to hold */
    FAP_TRACE_TX_FAILED = 4   /* tx: the write failed (some bytes may be on the wire) */
} fap_trace_status;

typedef struct fap_trace_frame {
    fap_trace_dir dir;
    fap_trace_status status;
    int64_t t_ns;             /* CLOCK_MONOTONIC ns (fap_port_now_ns): rx = when
                                 the frame's last byte was read, tx = after the write */
    const uint8_t *data;      /* raw wire bytes, escapes and checksum included */
    size_t len;
} fap_trace_frame;

typedef void (*fap_trace_fn)(void *ctx, const fap_trace_frame *f);

/* "ok", "bad_crc", "bad_frame", "truncated", "tx_failed" ("?" otherwise). */
const char *fap_trace_status_name(int status);

#ifdef __cplusplus
}
#endif
#endif /* FAP_TRACE_H */
