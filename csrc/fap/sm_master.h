/* FAP master state machine (sans-I/O): slave list, ID cycles, data cycles.
 * Driving protocol: see fap_sm.h. */
#ifndef LF_FAP_MASTER_H
#define LF_FAP_MASTER_H
#include "fap/fap_sm.h"

typedef enum lf_fap_master_state {
    LF_M_IDLE = 0,       /* nothing to do until a slave is added, data is queued or idc */
    LF_M_ID_WAIT,        /* QUERY_ID(cur) sent (or in the outbox), waiting for ID */
    LF_M_SLOT,           /* sending the master's own DATA frames */
    LF_M_POLL_WAIT,      /* SEND_DATA(cur) sent (or in the outbox), waiting for DATA_DONE */
} lf_fap_master_state;

typedef struct lf_fap_master {
    lf_fap_timing t;
    lf_fap_io io;
    lf_fap_master_state state;
    uint32_t listed;         /* bit i: slave i is on the list */
    uint32_t active;         /* bit i: slave i answered QUERY_ID since added / marked inactive */
    unsigned cur;            /* slave being queried or polled */
    uint32_t fresh;          /* added, not yet queried: ID cycle after this data cycle */
    lf_ns next_idc;          /* when inactive slaves are queried again */
    lf_ns wait_deadline;     /* answer / DATA_DONE / slot budget deadline */
    lf_fap_outbox out;
    uint8_t scratch[LF_FAP_MAX_DATA];
    lf_fap_sm_counts c;
    /* DATA sent to slave i since its last DATA_DONE: counted as
     * c.tx_unconfirmed if it is marked inactive instead (FAP has no ack). */
    uint32_t unconfirmed[LF_FAP_MAX_ID + 1];
} lf_fap_master;

void lf_fap_master_init(lf_fap_master *m, const lf_fap_timing *t, const lf_fap_io *io, lf_ns now);
/* 0, or -EINVAL (id not 1..31), -EEXIST (already listed). */
int lf_fap_master_add(lf_fap_master *m, unsigned id, lf_ns now);
/* 0, or -EINVAL, -ENOENT (not listed). */
int lf_fap_master_remove(lf_fap_master *m, unsigned id, lf_ns now);
/* The user queued data: an idle master starts a data cycle. */
void lf_fap_master_tx_queued(lf_fap_master *m, lf_ns now);
void lf_fap_master_on_frame(lf_fap_master *m, const lf_fap_frame *f, lf_ns now);
/* Call at (or after) lf_fap_master_deadline(). */
void lf_fap_master_on_timer(lf_fap_master *m, lf_ns now);
/* The port went and came back (a reopen): an answer awaited now died with
 * the link, so stop waiting for it (a DATA_DONE: the usual timeout path
 * at the next lf_fap_master_on_timer(), the loss counted; an ID: the ID
 * cycle starts again), and slaves marked inactive during the outage are
 * queried at once, not after the ID cycle time. */
void lf_fap_master_link_reset(lf_fap_master *m, lf_ns now);
/* The outbox frame has been transmitted at `now`. */
void lf_fap_master_sent(lf_fap_master *m, lf_ns now);
lf_ns lf_fap_master_deadline(const lf_fap_master *m);
static inline const lf_fap_outbox *lf_fap_master_outbox(const lf_fap_master *m)
{
    return &m->out;
}
static inline int lf_fap_master_is_active(const lf_fap_master *m, unsigned id)
{
    return id <= LF_FAP_MAX_ID && ((m->active >> id) & 1u);
}
#endif
