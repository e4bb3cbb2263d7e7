/* port_cancel.h - a port whose waits a stop can end.
 *
 * The port layer waits in poll(): for room when the line does not drain (a
 * pty nobody reads, a stalled far end: up to the write timeout per frame),
 * for the echo, for a reply until the caller's deadline. An engine that must
 * stop promptly opens its port through the real transport with one change:
 * every poll also watches a cancel fd, and once that is readable the wait
 * fails with ECANCELED, so the call in progress returns -ECANCELED at once.
 *
 * Two shapes: the engine owns the fd (lf_port_open_cancellable: fapx, the
 * exec master), or the port owns it and the engine only says "stop"
 * (lf_port_open_interruptible + lf_port_interrupt: the exec slave, whose
 * waits are all the port's). */
#ifndef LF_PORT_CANCEL_H
#define LF_PORT_CANCEL_H

#include "fap_port.h"

/* fap_port_open, with waits that end when *cancel_fd turns readable.
 * cancel_fd must outlive the port. */
int lf_port_open_cancellable(fap_port **out, const char *path, const fap_port_options *o,
                             const int *cancel_fd);

/* fap_port_open with the port's own interrupt (an eventfd it closes at
 * fap_port_close). */
int lf_port_open_interruptible(fap_port **out, const char *path, const fap_port_options *o);
/* From any thread or a signal handler (an atomic store and one write):
 * the wait in progress and every later one end with -ECANCELED; a port
 * opened otherwise only records it (lf_port_interrupted). Sticky. */
void lf_port_interrupt(fap_port *p);
/* 1 once lf_port_interrupt was called: an engine checks before working on
 * input a read returned at once (no wait, so no -ECANCELED). */
int lf_port_interrupted(const fap_port *p);

#endif
