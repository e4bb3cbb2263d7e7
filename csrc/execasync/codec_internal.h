/* What the engines need to know about the decoder beyond exec_async.h. */
#ifndef LF_EXEC_CODEC_INTERNAL_H
#define LF_EXEC_CODEC_INTERNAL_H

#include "exec_async.h"

/* True while the decoder is inside a frame (DLE STX seen, frame not ended). */
int lf_exec_rx_in_frame(const struct execAsyncStateDef *s);

#endif
