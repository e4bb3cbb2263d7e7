/* What the engines need to know about the decoder beyond exec_async.h. */
#ifndef LF_EXEC_CODEC_INTERNAL_H
#define LF_EXEC_CODEC_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "exec_async.h"
#include "common/trace.h"

/* True while the decoder is inside a frame (DLE STX seen, frame not ended). */
int lf_exec_rx_in_frame(const struct execAsyncStateDef *s);

/* The raw bytes of the frame being received, for the trace hook. */
typedef struct lf_exec_tap {
    uint8_t raw[EXEC_ASYNC_MAX_FRAME + 2];  /* longer frames are reported cut */
    size_t n;
    int restart;     /* the last report ended at a DLE STX that starts the next frame */
    int reported;
} lf_exec_tap;

/* execAsyncByteIn, and when `tr` has a hook, every frame it ends (good or
 * bad) reported as raw bytes through it. */
boolean lf_exec_byte_in_traced(byte v, struct execAsyncStateDef *s, byte *buf,
                               lf_exec_tap *tap, lf_trace *tr, int64_t now);
/* Report a partial frame that is being thrown away (TRUNCATED). */
void lf_exec_tap_abandon(lf_exec_tap *tap, lf_trace *tr, int64_t now);

/* A monitor's view of the decoder: execAsyncByteIn over a byte run, with
 * the stream offsets of each reported frame (good or bad), so the raw
 * bytes as sent can be shown. Sans-I/O. */
typedef struct lf_exec_scan {
    struct execAsyncStateDef st;     /* the receiver's own state */
    byte buf[EXEC_ASYNC_MAX_DATA];   /* its Buffer (unstuffed data) */
    uint64_t pos;                    /* stream offset of the next byte */
    uint64_t start;                  /* offset of the DLE of the current DLE STX */
    uint64_t rep_start, rep_end;     /* span [start, end) of the last report */
} lf_exec_scan;

void lf_exec_scan_init(lf_exec_scan *s);
/* Feed bytes until execAsyncByteIn reports (st.Status != NONE, span in
 * rep_start/rep_end) or p runs out; returns the bytes consumed. A FRAMING
 * report made at a DLE STX ends before that DLE STX (it starts the next). */
size_t lf_exec_scan_feed(lf_exec_scan *s, const byte *p, size_t n);
/* Short reason of a Status ("crc", "length", "framing"; NULL for GOOD). */
const char *lf_exec_status_reason(int status);

/* The fewest bytes still needed to end a frame from the decoder's state
 * (a lower bound: the data length is not sent). The engines sleep their
 * wire time instead of waking per byte (port/rx_pacing.h). */
size_t lf_exec_rx_missing(const struct execAsyncStateDef *s);

/* Wire length of the frame in progress (from its DLE STX) and of the last
 * one that ended: the engines expect the next frame as long as the last
 * (a master polling with one request size; the replies to it). */
typedef struct lf_exec_flen {
    size_t cur;    /* bytes of the frame in progress so far */
    size_t last;   /* bytes of the last frame that ended; 0 = none */
} lf_exec_flen;

/* After one byte went into the decoder s: was_in = lf_exec_rx_in_frame(s)
 * before it, done = what execAsyncByteIn returned. */
void lf_exec_flen_byte(lf_exec_flen *f, const struct execAsyncStateDef *s, int was_in, int done);
/* The bytes to ask the port for: the decoder's lower bound, or what is
 * left of `expect` bytes (a frame's expected wire length) if more. */
size_t lf_exec_rx_want(const struct execAsyncStateDef *s, const lf_exec_flen *f, size_t expect);

#endif
