/* FAP slave state machine (sans-I/O). Driving protocol: see fap_sm.h. */
#ifndef LF_FAP_SLAVE_H
#define LF_FAP_SLAVE_H
#include "fap/fap_sm.h"

typedef enum lf_fap_slave_state {
    LF_S_IDLE = 0,      /* listening */
    LF_S_ANSWER,        /* ID in the outbox */
    LF_S_TURN,          /* our turn: DATA frames, then DATA_DONE */
    LF_S_DONE,          /* DATA_DONE in the outbox */
} lf_fap_slave_state;

typedef struct lf_fap_slave {
    lf_fap_timing t;
    lf_fap_io io;
    unsigned id;
    lf_fap_slave_state state;
    lf_ns budget_end;        /* end of the current turn's send budget */
    int answer_pending;      /* QUERY_ID came while a frame was in the outbox */
    lf_ns last_polled;       /* last SEND_DATA or QUERY_ID for us (0 = never) */
    lf_fap_outbox out;
    uint8_t scratch[LF_FAP_MAX_DATA];
    lf_fap_sm_counts c;
} lf_fap_slave;

void lf_fap_slave_init(lf_fap_slave *s, unsigned id, const lf_fap_timing *t, const lf_fap_io *io);
void lf_fap_slave_on_frame(lf_fap_slave *s, const lf_fap_frame *f, lf_ns now);
void lf_fap_slave_sent(lf_fap_slave *s, lf_ns now);
static inline const lf_fap_outbox *lf_fap_slave_outbox(const lf_fap_slave *s)
{
    return &s->out;
}
/* A slave has no timers of its own: it only ever answers. */
static inline lf_ns lf_fap_slave_deadline(const lf_fap_slave *s)
{
    (void)s;
    return LF_NEVER;
}
#endif
