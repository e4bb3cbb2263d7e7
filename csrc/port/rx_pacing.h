/* rx_pacing.h - receive a frame without waking for every byte.
 *
 * A UART FIFO, a USB adapter or the paced virtual bus hand a frame over in
 * small pieces at wire speed; an engine that wakes for each piece spends
 * most of its CPU on wake-ups. Once the first bytes of a frame are in and
 * the decoder can say how many more the frame needs at least (from its
 * header, or a lower bound from the framing), those bytes cannot arrive
 * sooner than their wire time (10 bits per byte at the port's baud), so
 * the engine may sleep that long and read them together.
 *
 * The sleep covers all but the LAST missing byte: the engine then waits
 * for that one on the fd as usual, so the answer is never later than with
 * per-byte wake-ups (a sleep that ended just before the last byte would
 * otherwise cost up to a character time). Bytes already queued (an
 * unpaced pty, a late reader) are read at once, without sleeping.
 * A baud of 0 (unknown) never sleeps. */
#ifndef LF_RX_PACING_H
#define LF_RX_PACING_H

#include <stddef.h>
#include <sys/types.h>

#include "common/mono_clock.h"
#include "fap_port.h"

/* How long to sleep before reading when `missing` more bytes are due:
 * (missing - 1) character times, 0 when missing < 2 or baud is 0. */
lf_ns lf_rx_hold_ns(unsigned baud, size_t missing);

/* Read into buf (capacity n) until `want` bytes are in, sleeping the wire
 * time of the missing bytes instead of waking per byte:
 *  1. nothing queued: wait for the first bytes until deadline_ns (as
 *     fap_port_read; 0 = do not wait);
 *  2. while fewer than want: if 2 or more are missing, sleep their wire
 *     time but one (never past deadline_ns) and read what is queued;
 *  3. return once want is reached, one byte is missing (the caller waits
 *     for it on the fd), or a sleep brought nothing (the wire stalled).
 * Returns the bytes read (0: deadline passed with nothing), or a negative
 * error as fap_port_read when nothing was read (with bytes in hand the
 * error is left for the next call). */
ssize_t lf_port_read_paced(fap_port *p, void *buf, size_t n, size_t want,
                           int64_t deadline_ns);

#endif
