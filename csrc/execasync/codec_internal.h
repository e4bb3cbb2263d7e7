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

#endif
