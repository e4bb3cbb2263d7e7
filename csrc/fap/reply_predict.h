/* reply_predict.h - when a polled slave's DATA_DONE can be complete
 * (sans-I/O; the FAP master engine's idle poll cycle, issue 24).
 *
 * A master that waits for a reply on the port wakes for the reply's first
 * piece, again at the end of the hold that follows (rx_pacing.h) and once
 * more for the last byte or two: about 3.5 wake-ups per poll cycle at
 * 115200. It does not have to: the reply cannot be complete before its own
 * SEND_DATA's end on the wire + the slave's turnaround + the DATA_DONE's
 * wire time (15 bytes, fixed). The turnaround is learned per slave, so the
 * engine can sleep (without the port in its epoll set) until that moment
 * and read the whole reply in one wake-up.
 *
 * Learning: an observed reply (the engine watched the port) gives an
 * upper bound of the turnaround (the engine's wake-up latency on top);
 * the estimate takes the smallest. A predicted read that finds the reply
 * complete lowers it by a step (the slave may be faster than predicted:
 * the master reacts late by the difference, so the estimate keeps probing
 * down), one that finds bytes missing raises it by the same step, however
 * late the reply was (one late reply does not drag the estimate). The
 * step is an eighth of a character time, or 1/16 of the estimate when
 * more. So the estimate oscillates around the reply's usual end: about
 * one predicted read in two finds the last byte missing, and the engine
 * then waits for it on the port (never later than the wire). Every 64th
 * poll of a slave is observed again.
 *
 * Only on a device (the kernel's tty, not a network transport) and only
 * once a reply was seen no sooner than the port's baud allows: an unpaced
 * pty, a link faster than the baud or an unknown baud keep the observed
 * path (lf_reply_predict_when() answers 0). */
#ifndef LF_FAP_REPLY_PREDICT_H
#define LF_FAP_REPLY_PREDICT_H
#include <stddef.h>
#include "common/mono_clock.h"
#include "fap/codec.h"

#define LF_REPLY_PREDICT_OBSERVE_EVERY 64   /* polls of one slave between observations */

typedef struct lf_reply_predict {
    lf_ns ct;                       /* character time at the port's baud; 0: never predict */
    int paced;                      /* the last observed reply came at the baud's pace */
    unsigned since_observe[LF_FAP_MAX_ID + 1];
    lf_ns ta[LF_FAP_MAX_ID + 1];    /* learned turnaround per slave; -1: unknown */
} lf_reply_predict;

/* baud: the port's; device: a local tty (not a network transport). */
void lf_reply_predict_init(lf_reply_predict *p, unsigned baud, int device);

/* A SEND_DATA to slave id ended on the wire at sent_end: when to read its
 * DATA_DONE in one go, or 0: watch the port (an observation). */
lf_ns lf_reply_predict_when(lf_reply_predict *p, unsigned id, lf_ns sent_end);

/* Watching the port, the DATA_DONE from id was complete at now. */
void lf_reply_predict_observed(lf_reply_predict *p, unsigned id, lf_ns sent_end, lf_ns now);

/* The read at the predicted time found the DATA_DONE complete (missing
 * 0), or that many bytes of it missing (the whole frame when nothing
 * came). A slave that sends DATA in its turn is not reported: its reply
 * is longer than the prediction by design. */
void lf_reply_predict_outcome(lf_reply_predict *p, unsigned id, size_t missing);

#endif
