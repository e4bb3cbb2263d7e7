/* Internal to the mikroC component: shared by the context API and the
 * vendor-style global routines. */
#ifndef LF_MIKROC_INTERNAL_H
#define LF_MIKROC_INTERNAL_H
#include <stddef.h>
#include <stdint.h>
#include "fap_port.h"
#include "fap_trace.h"
#include "mikroc_rs485.h"

/* Open path with opts (NULL = port defaults) and baud (0 = keep opts').
 * 0 and *out set, or a negative error. */
int lf_mikroc_port_open(fap_port **out, const char *path, unsigned baud,
                        const fap_port_options *opts);

/* Call c->trace (set) with one frame, stamped now. */
struct mikrocRS485_ctx;
void lf_mikroc_trace(struct mikrocRS485_ctx *c, fap_trace_dir dir, fap_trace_status status,
                     const uint8_t *data, size_t len);

/* The fewest bytes still needed to end a frame from the decoder's state
 * (the whole minimal frame when none has started). refill() sleeps their
 * wire time instead of waking per byte (port/rx_pacing.h). */
size_t lf_mikroc_missing(const mikrocRS485_decoder *d);
/* The bytes to ask the port for: what is left of a full frame
 * (MIKROC_RS485_FRAME_MAX: three data bytes, what nodes send) until
 * DATALEN says the count, then lf_mikroc_missing. A shorter frame costs
 * at most the difference in wire time (lf_port_read_frame's bound). */
size_t lf_mikroc_expect(const mikrocRS485_decoder *d);
#endif
