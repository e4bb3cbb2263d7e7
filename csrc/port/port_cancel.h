/* port_cancel.h - a port whose waits a stop can end.
 *
 * The port layer waits in poll(): for room when the line does not drain (a
 * pty nobody reads, a stalled far end: up to the write timeout per frame),
 * for the echo, for a reply until the caller's deadline. An engine that must
 * stop promptly (fapx_close, execMasterStop) opens its port through the real
 * backend with one change: every poll also watches *cancel_fd (an eventfd
 * the engine owns), and once that is readable the wait fails with ECANCELED,
 * so the call in progress returns -ECANCELED at once. */
#ifndef LF_PORT_CANCEL_H
#define LF_PORT_CANCEL_H

#include "fap_port.h"

/* fap_port_open, with waits that end when *cancel_fd turns readable.
 * cancel_fd must outlive the port. */
int lf_port_open_cancellable(fap_port **out, const char *path, const fap_port_options *o,
                             const int *cancel_fd);

#endif
