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
 * What a complete read costs: the master reacts late by the time the reply
 * waited, which the read cannot see. So a slave is predicted only while
 * its turnaround is tight (31 slaves served by one loaded process, each
 * polled once every 31 cycles, had 500-650 us turnarounds scattered by
 * more than a frame: 64 % of reads found the reply complete, 30 % found
 * more than the last byte missing, and the master's reaction doubled):
 * - before predicting, 4 observations in a row must lie within a
 *   character time of each other (else 4 more are taken, and so on); the
 *   estimate starts at their smallest, the low end;
 * - a predicted slave whose reads find more than the last byte missing in
 *   4 of its last 8 (a turnaround spread wider than a character time,
 *   which makes the complete reads late by as much) goes back to that;
 * - a slave that sent DATA in its turn is observed until a turn without
 *   (its reply is a DATA frame and a DATA_DONE; predicting it cost ~12 %
 *   of a data exchange's rate at 115200);
 * - from the third complete read in a row the down step doubles each
 *   time, up to 8x (an estimate that is late comes down in a few polls);
 *   a read finding bytes missing resets it.
 *
 * Only on a device (the kernel's tty, not a network transport) and only
 * once a reply was seen no sooner than the port's baud allows: an unpaced
 * pty, a link faster than the baud or an unknown baud keep the observed
 * path (lf_reply_predict_when() answers 0). */
#ifndef LF_FAP_REPLY_PREDICT_H
#define LF_FAP_REPLY_PREDICT_H
#include <stddef.h>
#include <stdint.h>
#include "common/mono_clock.h"
#include "fap/codec.h"

#define LF_REPLY_PREDICT_OBSERVE_EVERY 64   /* polls of one slave between observations */
#define LF_REPLY_PREDICT_TIGHT_N 4          /* observations within a character time: predict */
#define LF_REPLY_PREDICT_WIDE_OF_8 4        /* late reads (> 1 byte missing) of the last 8: stop */

typedef struct lf_reply_predict {
    lf_ns ct;                       /* character time at the port's baud; 0: never predict */
    int paced;                      /* the last observed reply came at the baud's pace */
    unsigned since_observe[LF_FAP_MAX_ID + 1];
    lf_ns ta[LF_FAP_MAX_ID + 1];    /* learned turnaround per slave; -1: unknown */
    unsigned downs[LF_FAP_MAX_ID + 1];  /* complete reads in a row: the down step doubles */
    uint8_t late[LF_FAP_MAX_ID + 1];    /* the last 8 reads, a bit each: > 1 byte missing */
    uint8_t tight[LF_FAP_MAX_ID + 1];   /* its turnaround is tight: predicted */
    uint8_t data[LF_FAP_MAX_ID + 1];    /* it sent DATA in its last turn: observed */
    unsigned obs_n[LF_FAP_MAX_ID + 1];  /* not yet: observations in the current run, */
    lf_ns obs_lo[LF_FAP_MAX_ID + 1];    /* their smallest */
    lf_ns obs_hi[LF_FAP_MAX_ID + 1];    /* and largest turnaround */
} lf_reply_predict;

/* baud: the port's; device: a local tty (not a network transport). */
void lf_reply_predict_init(lf_reply_predict *p, unsigned baud, int device);

/* A SEND_DATA to slave id ended on the wire at sent_end: when to read its
 * DATA_DONE in one go, or 0: watch the port (an observation). */
lf_ns lf_reply_predict_when(lf_reply_predict *p, unsigned id, lf_ns sent_end);

/* Watching the port, the DATA_DONE from id was complete at now. */
void lf_reply_predict_observed(lf_reply_predict *p, unsigned id, lf_ns sent_end, lf_ns now);

/* Slave id's turn ended; sent_data: it sent DATA in it. A slave that
 * sends DATA is observed on its next polls (its reply is a DATA frame and
 * a DATA_DONE, whose end the estimate does not know) until a turn with
 * none. */
void lf_reply_predict_turn(lf_reply_predict *p, unsigned id, int sent_data);

/* The read at the predicted time found the DATA_DONE complete (missing
 * 0), or that many bytes of it missing (the whole frame when nothing
 * came). A slave that sends DATA in its turn is not reported: its reply
 * is longer than the prediction by design. */
void lf_reply_predict_outcome(lf_reply_predict *p, unsigned id, size_t missing);

#endif
