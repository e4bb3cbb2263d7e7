/* FAP slave state machine. It transmits only when the master tells it to:
 * QUERY_ID for its ID -> ID at once; SEND_DATA for its ID -> queued DATA
 * frames (to the master or other slaves) while the send budget lasts, then
 * DATA_DONE (what is left waits for the next turn). DATA addressed to it is
 * delivered; every other frame is ignored. */
#include "fap/sm_slave.h"
#include <string.h>

void lf_fap_slave_init(lf_fap_slave *s, unsigned id, const lf_fap_timing *t, const lf_fap_io *io)
{
    memset(s, 0, sizeof *s);
    s->t = *t;
    lf_fap_timing_fill(&s->t);
    s->io = *io;
    s->id = id;
    s->state = LF_S_IDLE;
}

/* Next DATA of our turn, or DATA_DONE when the queue is empty or the budget spent. */
static void turn_next(lf_fap_slave *s, lf_ns now)
{
    if (lf_fap_next_data(&s->out, &s->io, s->scratch, s->id, now, s->budget_end, &s->c)) {
        s->state = LF_S_TURN;
        return;
    }
    s->state = LF_S_DONE;
    lf_fap_outbox_put(&s->out, LF_FAP_DATA_DONE, 0, s->id, NULL, 0);
}

void lf_fap_slave_on_frame(lf_fap_slave *s, const lf_fap_frame *f, lf_ns now)
{
    if (f->dst != s->id || f->src == s->id)
        return;                         /* not for us (or our own echo) */
    switch (f->msg) {
    case LF_FAP_QUERY_ID:
        if (f->src != 0)
            break;
        /* A query during our turn means the master gave up on it: the
         * turn ends with ID. A frame already in the outbox goes first. */
        s->last_polled = now;
        if (s->out.len) {
            s->answer_pending = 1;
        } else {
            s->state = LF_S_ANSWER;
            lf_fap_outbox_put(&s->out, LF_FAP_ID, 0, s->id, NULL, 0);
        }
        if (s->io.event)
            s->io.event(s->io.ctx, LF_FAP_EV_QUERIED, s->id, now);
        return;
    case LF_FAP_SEND_DATA:
        if (f->src != 0 || s->out.len)
            break;
        s->last_polled = now;
        s->budget_end = now + s->t.send_budget;
        s->c.polls++;
        turn_next(s, now);
        return;
    case LF_FAP_DATA:
        s->c.data_rx++;
        if (s->io.deliver)
            s->io.deliver(s->io.ctx, f->src, f->data, f->len, now);
        return;
    default:
        break;
    }
    s->c.unexpected++;
}

void lf_fap_slave_sent(lf_fap_slave *s, lf_ns now)
{
    s->out.len = 0;
    if (s->answer_pending) {
        s->answer_pending = 0;
        s->state = LF_S_ANSWER;
        lf_fap_outbox_put(&s->out, LF_FAP_ID, 0, s->id, NULL, 0);
    } else if (s->state == LF_S_TURN)
        turn_next(s, now);
    else
        s->state = LF_S_IDLE;
}
