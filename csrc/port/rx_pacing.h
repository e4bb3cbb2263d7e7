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
 * "Their wire time" is that of the link actually observed, not of the
 * baud the port was opened with: a pty in front of socat or ser2net, a
 * virtual bus paced at another rate or a network transport deliver at
 * their own pace. So no hold comes before the frame's second piece: the
 * bytes it brought over the time since the first piece give the link's
 * character time, and the hold uses that (never more than the baud's
 * character time; a baud of 0 trusts the observation alone). A wrong or
 * meaningless local baud costs at most the one extra wake-up for that
 * observation per frame.
 *
 * The sleep covers all but the LAST missing byte, less a margin for the
 * engine's wake-up latency: the engine then waits for the rest on the fd
 * as usual, so the answer is not later than with per-byte wake-ups (a
 * sleep that ended after the last byte would delay it). Bytes already queued (an
 * unpaced pty, a late reader) are read at once, without sleeping.
 * A baud of 0 (unknown) never sleeps. */
#ifndef LF_RX_PACING_H
#define LF_RX_PACING_H

#include <stddef.h>
#include <sys/types.h>

#include "common/mono_clock.h"
#include "fap_port.h"
#include "port/rx_plan.h"   /* the decisions; this file's reads are their blocking driver */

/* Read into buf (capacity n) until `want` bytes are in, sleeping the wire
 * time of the missing bytes instead of waking per byte:
 *  1. nothing queued: wait for the first bytes until deadline_ns (as
 *     fap_port_read; 0 = do not wait);
 *  2. fewer than want: wait for the next piece on the fd (until
 *     deadline_ns), which gives the link's observed pace;
 *  3. while fewer than want and the planner (lf_rx_plan_piece) holds for
 *     the missing bytes: sleep that long (never past deadline_ns), read
 *     what is queued;
 *  4. return once want is reached, the hold is 0 (the caller waits for the
 *     last bytes on the fd), or a wait brought nothing (the wire stalled).
 * Returns the bytes read (0: deadline passed with nothing), or a negative
 * error as fap_port_read when nothing was read (with bytes in hand the
 * error is left for the next call). */
ssize_t lf_port_read_paced(fap_port *p, void *buf, size_t n, size_t want,
                           int64_t deadline_ns);

/* lf_port_read_paced for a listener that waits for requests (the exec
 * slave): the first bytes until deadline_ns, the rest of `want` no longer
 * than their wire time at the port's baud (want character times from when
 * the first bytes were read; never past deadline_ns), so that a partial
 * frame reaches the decoder instead of waiting out the caller's deadline.
 * Same returns. */
ssize_t lf_port_read_frame(fap_port *p, void *buf, size_t n, size_t want,
                           int64_t deadline_ns);

/* lf_port_read_frame keeping the link's pace from one frame to the next
 * in *link (rx_plan.h): link->at_baud set, the rest is held from the
 * first bytes at the baud's pace without waiting for a second piece; such
 * a hold that woke on time and found all `want` bytes in clears it (the
 * link may be faster); a second piece as the wire brought it sets it when
 * the link ran at the baud (not faster). */
ssize_t lf_port_read_frame_kept(fap_port *p, void *buf, size_t n, size_t want,
                                int64_t deadline_ns, lf_rx_link *link);

/* The port's own link belief for lf_port_read_frame_kept, for engines
 * whose state has no room for one (the mikroC context). Its reader's. */
lf_rx_link *lf_port_rx_link(fap_port *p);

/* When the last frame written on p can have left the wire: the write's
 * start plus its wire time at the port's baud (0: nothing written). An
 * answer to it cannot be complete before this plus the answer's own wire
 * time. */
int64_t lf_port_tx_end_ns(fap_port *p);

/* lf_port_read_frame_kept for a reply whose expected length (want) and
 * earliest completion are known (the exec master: the last reply's length
 * from that node, after the request's end; lf_rx_plan_reply's
 * LF_RX_REPLY_EXPECTED): with link->at_baud set, not_before ahead and
 * want long enough for a hold (lf_rx_hold_ct_ns > 0), one sleep until
 * not_before (never past deadline_ns), one read; the rest, if any, held at
 * the baud's pace (bounded by its wire time); nothing yet, or at_baud
 * clear: lf_port_read_frame_kept. A reply found complete by a wake-up
 * within a character time of not_before clears at_baud (at the baud it
 * could not be: the link is faster). A stop during the sleep waits at most
 * until not_before. Same returns. */
ssize_t lf_port_read_reply(fap_port *p, void *buf, size_t n, size_t want, int64_t not_before,
                           int64_t deadline_ns, lf_rx_link *link);

/* fap_port_read whose deadline holds to the nanosecond, for short waits
 * that are part of the wire timing (the exec slave watching the line
 * through its turnaround delay): the port's poll counts whole
 * milliseconds, rounded up, so it waits in it until a millisecond before
 * deadline_ns, sleeps the rest and takes what is queued then. Same
 * returns; a stop ends the poll part at once, the sleep (under 1 ms) runs
 * out. */
ssize_t lf_port_read_until(fap_port *p, void *buf, size_t n, int64_t deadline_ns);

#endif
