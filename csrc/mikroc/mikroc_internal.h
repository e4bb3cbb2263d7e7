/* Internal to the mikroC component: shared by the context API and the
 * vendor-style global routines. */
#ifndef LF_MIKROC_INTERNAL_H
#define LF_MIKROC_INTERNAL_H
#include "fap_port.h"

/* Open path with opts (NULL = port defaults) and baud (0 = keep opts').
 * 0 and *out set, or a negative error. */
int lf_mikroc_port_open(fap_port **out, const char *path, unsigned baud,
                        const fap_port_options *opts);
#endif
