/* What the engines need to know about the decoder beyond exec_async.h. */
#ifndef LF_EXEC_CODEC_INTERNAL_H
#define LF_EXEC_CODEC_INTERNAL_H

#include <stddef.h>

#include "exec_async.h"

/* True while the decoder is inside a frame (DLE STX seen, frame not ended). */
int lf_exec_rx_in_frame(const struct execAsyncStateDef *s);

/* The fewest bytes still needed to end a frame from the decoder's state
 * (a lower bound: the data length is not sent). The engines sleep their
 * wire time instead of waking per byte (port/rx_pacing.h). */
size_t lf_exec_rx_missing(const struct execAsyncStateDef *s);

#endif
