/* rx_plan.h - when to read a frame or a reply: the one decision, sans-I/O.
 *
 * A reader (the blocking reads of rx_pacing.c: exec async, mikroC; the
 * FAP engine's epoll loop) tells the planner what a read brought and when
 * (it passes `now`: the planner reads no clock, touches no fd), and the
 * planner answers what to do next:
 *  - LF_RX_SLEEP_UNTIL t: the bytes due cannot be in before t; sleep
 *    without watching the fd, then read what is queued;
 *  - LF_RX_WATCH_UNTIL t: wait for the fd (t: the reader's deadline);
 *  - LF_RX_COMPLETE: nothing more to wait for (the frame is in, or a sleep
 *    ended at the reader's deadline).
 * with the reason (lf_rx_why), which the reader may act on (the blocking
 * read leaves LF_RX_LAST's wait on the fd to its caller).
 *
 * The rules (each measured: bench/PERFORMANCE.md, "Idle master, second
 * to fourth pass" and "exec async master and mikroC, the reply wait"):
 *  - a frame's rest is held for the wire time of all its missing bytes
 *    but the last, less a margin for the reader's wake-up latency
 *    (lf_rx_hold_ct_ns), at the pace the link showed: the bytes its
 *    second piece brought over the time since the first (never slower
 *    than the baud; a baud of 0 trusts the observation alone);
 *  - a link seen at the baud (lf_rx_link, kept from frame to frame) is
 *    held from a frame's first piece at the baud's pace, without waiting
 *    for a second piece; a hold that woke on time and found its frame
 *    complete clears that (the link may be faster);
 *  - a reply that cannot be complete before a known time (the request's
 *    end plus the reply's wire time, or the FAP predictor's time,
 *    fap/reply_predict.h) is slept for until then, then read at once. */
#ifndef LF_RX_PLAN_H
#define LF_RX_PLAN_H

#include <stddef.h>

#include "common/mono_clock.h"

/* How long to sleep before reading when `missing` more bytes are due:
 * their wire time but the last byte's, less a margin for the reader's own
 * wake-up latency (the larger of a character time and 150 us); 0 when that
 * is under 100 us (not worth a timer: short frames at 1 Mbaud) or the
 * baud is 0. */
lf_ns lf_rx_hold_ns(unsigned baud, size_t missing);
/* The same for a character time ct (ns per byte) instead of a baud. */
lf_ns lf_rx_hold_ct_ns(lf_ns ct, size_t missing);

/* n bytes that came `gap` ns after the previous piece ran at the baud's
 * character time ct, not faster (within 30 %: a wake-up is never early). */
int lf_rx_at_baud(lf_ns gap, lf_ns ct, size_t n);

/* The rest of a frame no longer than its wire time: now + n character
 * times, or deadline when that is sooner. */
lf_ns lf_rx_rest_deadline(lf_ns ct, size_t n, lf_ns now, lf_ns deadline);

/* The belief "this link runs at the port's baud", kept from frame to
 * frame by its reader (one per reader: the FAP engine, an exec master or
 * slave, the port for mikroC). Only the planner changes it. */
typedef struct lf_rx_link {
    int at_baud;
} lf_rx_link;

typedef enum lf_rx_act {
    LF_RX_COMPLETE,
    LF_RX_SLEEP_UNTIL,
    LF_RX_WATCH_UNTIL,
} lf_rx_act;

typedef enum lf_rx_why {
    LF_RX_DONE,          /* complete: nothing missing */
    LF_RX_DEADLINE,      /* complete: the sleep ended at the reader's deadline */
    LF_RX_OBSERVE,       /* watch: the next piece as the wire brings it shows the pace */
    LF_RX_LAST,          /* watch: the last byte(s), too few to be worth a hold */
    LF_RX_HOLD,          /* sleep: the rest at the pace the frame showed */
    LF_RX_HOLD_KEPT,     /* sleep: the rest at the baud's pace, from the first piece */
    LF_RX_REPLY,         /* sleep: the reply cannot be complete before */
    LF_RX_REPLY_REST,    /* sleep (predicted) or watch (expected): a reply's rest */
} lf_rx_why;

typedef struct lf_rx_action {
    lf_rx_act act;
    lf_rx_why why;
    lf_ns until;         /* SLEEP_UNTIL, WATCH_UNTIL: until then */
} lf_rx_action;

/* Where the reply wait is (the FAP engine's prediction stages). */
typedef enum lf_rx_reply_stage {
    LF_RX_REPLY_NONE,    /* no reply slept for */
    LF_RX_REPLY_ASLEEP,  /* asleep until the reply can be complete */
    LF_RX_REPLY_HOLD,    /* it was not: asleep for its rest at the baud's pace */
} lf_rx_reply_stage;

/* How the reply's earliest time was found, and so which rules apply. */
typedef enum lf_rx_reply_mode {
    /* exec async and mikroC masters: the request's end plus the expected
     * reply's wire time; slept for only on a link believed at the baud and
     * a reply long enough for a hold */
    LF_RX_REPLY_EXPECTED,
    /* the FAP master: fap/reply_predict.h's time, which judged the link
     * itself (its own pace check, a device only) */
    LF_RX_REPLY_PREDICTED,
} lf_rx_reply_mode;

/* One reader's plan: its link, the frame in progress, the reply wait. */
typedef struct lf_rx_plan {
    lf_ns ct;            /* the baud's character time; 0: baud unknown */
    lf_rx_link *link;    /* the belief; NULL: not kept (every frame observes) */
    /* Which on-time complete hold clears the belief: any (the FAP engine)
     * or only one taken on it (the blocking reads); as each was measured. */
    int any_hold_clears;
    lf_ns t_last;        /* when the frame's previous piece was read; 0: none */
    int observed;        /* the frame's pace is known (a second piece, or the belief) */
    int trusted;         /* the frame was held on the belief from its first piece */
    int capped;          /* the sleep asked for ends at the reader's deadline */
    lf_rx_reply_stage stage;
} lf_rx_plan;

/* baud: the port's (0 unknown); link may be NULL. */
void lf_rx_plan_init(lf_rx_plan *pl, unsigned baud, lf_rx_link *link, int any_hold_clears);

/* What a read brought. */
typedef struct lf_rx_piece {
    size_t n;            /* bytes, > 0 */
    size_t missing;      /* the frame still needs at least that many (0: complete) */
    int first;           /* the piece starts a frame */
    lf_ns now;           /* when it was read */
    lf_ns slept_to;      /* read at the end of a sleep due then; 0: the fd brought it */
    lf_ns deadline;      /* the reader's: no sleep past it (LF_NEVER: none) */
} lf_rx_piece;

/* A piece of a frame was read: update the belief, say what next.
 * COMPLETE (DONE: nothing missing; DEADLINE: the sleep before this read
 * ended at the deadline), SLEEP_UNTIL (HOLD, HOLD_KEPT: never past the
 * deadline) or WATCH_UNTIL the deadline (OBSERVE: the pace is not known
 * yet; LAST: too little left for a hold). */
lf_rx_action lf_rx_plan_piece(lf_rx_plan *pl, const lf_rx_piece *in);

/* A request went: should the reply be slept for? not_before: the earliest
 * the reply can be complete (0: not known); want: its expected length
 * (EXPECTED). SLEEP_UNTIL min(not_before, deadline) (REPLY), or
 * WATCH_UNTIL deadline (OBSERVE: read it as any frame). */
lf_rx_action lf_rx_plan_reply(lf_rx_plan *pl, lf_rx_reply_mode mode, size_t want,
                              lf_ns not_before, lf_ns now, lf_ns deadline);

/* What the read at a reply sleep's end found. */
typedef struct lf_rx_reply_read {
    size_t got;          /* bytes the read brought (0: none) */
    size_t want;         /* the reply's expected length */
    size_t missing;      /* PREDICTED: the decoder's count (0: none in progress) */
    int done;            /* PREDICTED: the reply was taken (complete) */
    lf_ns now;
    lf_ns slept_to;      /* when the sleep was due to end */
    lf_ns deadline;      /* EXPECTED: the reader's; PREDICTED: the frame's gap deadline */
} lf_rx_reply_read;

/* The read at the end of a reply's sleep (stage ASLEEP or HOLD).
 * EXPECTED: COMPLETE (DEADLINE: the sleep ended at the deadline; DONE: all
 * in, and a wake within a character time of the sleep's end clears the
 * belief: at the baud the reply could not have been complete), WATCH_UNTIL
 * the rest's deadline (REPLY_REST: bounded by its wire time; read it as a
 * frame, lf_rx_plan_piece) or WATCH_UNTIL deadline (OBSERVE: nothing yet).
 * PREDICTED: after ASLEEP with more than the last byte missing (nothing
 * at all: the whole reply), SLEEP_UNTIL all but the last can be in at
 * the baud, no margin (REPLY_REST, stage HOLD); else WATCH (the port as
 * usual: DONE, LAST). */
lf_rx_action lf_rx_plan_reply_read(lf_rx_plan *pl, lf_rx_reply_mode mode,
                                   const lf_rx_reply_read *in);

/* A frame went while a predicted sleep was pending: 1 when that sleep is
 * void (asleep for a reply, or for a rest whose frame is gone: missing 0),
 * and the stage is reset; 0: a frame is arriving, its hold stands. */
int lf_rx_plan_sent(lf_rx_plan *pl, size_t missing);

#endif
