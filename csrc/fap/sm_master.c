/* FAP master state machine. Rules (docs/protocols.md, FAP):
 * - ID cycle: QUERY_ID to each listed slave that is not active, in ID
 *   order; an ID from that slave within id_answer makes it active.
 * - Data cycle: the master's own queued DATA (within send_budget), then
 *   SEND_DATA to each active slave in ID order, waiting for its DATA_DONE
 *   up to data_done. A missing DATA_DONE marks the slave inactive and
 *   starts an ID cycle at once.
 * - After a data cycle: an ID cycle if a slave was added, or if a slave is
 *   inactive and idc has passed since the last ID cycle began; otherwise
 *   the next data cycle (back to back while a slave is active); with no
 *   active slave and no queued data the master idles until idc, an added
 *   slave or queued data. */
#include "fap/sm_master.h"
#include <errno.h>
#include <string.h>

static void start_id_cycle(lf_fap_master *m, lf_ns now);
static void start_data_cycle(lf_fap_master *m, lf_ns now);

static int listed(const lf_fap_master *m, unsigned id)
{
    return (m->listed >> id) & 1u;
}

static void emit_event(lf_fap_master *m, int type, unsigned id, lf_ns now)
{
    if (m->io.event)
        m->io.event(m->io.ctx, type, id, now);
}

void lf_fap_master_init(lf_fap_master *m, const lf_fap_timing *t, const lf_fap_io *io, lf_ns now)
{
    memset(m, 0, sizeof *m);
    m->t = *t;
    lf_fap_timing_fill(&m->t);
    m->io = *io;
    m->state = LF_M_IDLE;
    m->next_idc = now;
    m->wait_deadline = LF_NEVER;
}

/* Query the next listed, non-active slave after m->cur, or finish the ID cycle. */
static void id_next(lf_fap_master *m, lf_ns now)
{
    for (unsigned id = m->cur + 1; id <= LF_FAP_MAX_ID; id++) {
        if (listed(m, id) && !((m->active >> id) & 1u)) {
            m->cur = id;
            m->fresh &= ~(1u << id);
            m->state = LF_M_ID_WAIT;
            m->wait_deadline = LF_NEVER;         /* set when the frame has gone */
            lf_fap_outbox_put(&m->out, LF_FAP_QUERY_ID, id, 0, NULL, 0);
            return;
        }
    }
    m->c.id_cycles++;
    start_data_cycle(m, now);
}

static void start_id_cycle(lf_fap_master *m, lf_ns now)
{
    m->next_idc = now + m->t.idc;
    m->cur = 0;
    id_next(m, now);
}

/* After a complete data cycle: decide what comes next. */
static void after_cycle(lf_fap_master *m, lf_ns now)
{
    uint32_t inactive = m->listed & ~m->active;
    if ((m->fresh & m->listed) || (inactive && now >= m->next_idc))
        start_id_cycle(m, now);
    else
        start_data_cycle(m, now);
}

/* SEND_DATA to the next active slave after m->cur, or end the data cycle. */
static void poll_next(lf_fap_master *m, lf_ns now)
{
    for (unsigned id = m->cur + 1; id <= LF_FAP_MAX_ID; id++) {
        if ((m->listed & m->active) >> id & 1u) {
            m->cur = id;
            m->state = LF_M_POLL_WAIT;
            m->wait_deadline = LF_NEVER;
            lf_fap_outbox_put(&m->out, LF_FAP_SEND_DATA, id, 0, NULL, 0);
            return;
        }
    }
    m->c.cycles++;
    after_cycle(m, now);
}

/* One more DATA frame of the master's slot (1), or on to polling (0). */
static int slot_next(lf_fap_master *m, lf_ns now)
{
    if (!lf_fap_next_data(&m->out, &m->io, m->scratch, 0, now, m->wait_deadline, &m->c))
        return 0;
    unsigned dst = m->out.dst;       /* 1..31: next_data dropped the rest */
    if ((m->listed & m->active) >> dst & 1u)
        m->unconfirmed[dst]++;
    else
        m->c.tx_to_inactive++;       /* nobody known to listen: most likely lost */
    m->state = LF_M_SLOT;
    return 1;
}

static void start_data_cycle(lf_fap_master *m, lf_ns now)
{
    m->cur = 0;
    m->wait_deadline = now + m->t.send_budget;
    if (slot_next(m, now))
        return;
    if (m->listed & m->active) {
        poll_next(m, now);
        return;
    }
    /* Nobody to poll: a slave added during the last ID cycle (below the
     * one being queried then) is queried now; else sleep until idc or an
     * input. */
    if (m->fresh & m->listed) {
        start_id_cycle(m, now);
        return;
    }
    m->state = LF_M_IDLE;
    m->wait_deadline = LF_NEVER;
}

int lf_fap_master_add(lf_fap_master *m, unsigned id, lf_ns now)
{
    if (id == 0 || id > LF_FAP_MAX_ID)
        return -EINVAL;
    if (listed(m, id))
        return -EEXIST;
    m->listed |= 1u << id;
    m->active &= ~(1u << id);
    m->fresh |= 1u << id;
    if (m->state == LF_M_IDLE && m->out.len == 0)
        start_id_cycle(m, now);
    return 0;
}

int lf_fap_master_remove(lf_fap_master *m, unsigned id, lf_ns now)
{
    if (id == 0 || id > LF_FAP_MAX_ID)
        return -EINVAL;
    if (!listed(m, id))
        return -ENOENT;
    m->listed &= ~(1u << id);
    m->active &= ~(1u << id);
    /* Stop waiting for a slave that is gone (unless its frame is still in
     * the outbox: lf_fap_master_sent() moves on then). */
    if (m->cur == id && m->out.len == 0) {
        if (m->state == LF_M_ID_WAIT)
            id_next(m, now);
        else if (m->state == LF_M_POLL_WAIT)
            poll_next(m, now);
    }
    return 0;
}

void lf_fap_master_tx_queued(lf_fap_master *m, lf_ns now)
{
    if (m->state == LF_M_IDLE && m->out.len == 0)
        start_data_cycle(m, now);
}

void lf_fap_master_sent(lf_fap_master *m, lf_ns now)
{
    m->out.len = 0;
    switch (m->state) {
    case LF_M_ID_WAIT:
        if (!listed(m, m->cur))
            id_next(m, now);
        else
            m->wait_deadline = now + m->t.id_answer;
        break;
    case LF_M_POLL_WAIT:
        if (!listed(m, m->cur))
            poll_next(m, now);
        else
            m->wait_deadline = now + m->t.data_done;
        break;
    case LF_M_SLOT:
        if (!slot_next(m, now))
            poll_next(m, now);
        break;
    case LF_M_IDLE:
        break;
    }
}

void lf_fap_master_on_frame(lf_fap_master *m, const lf_fap_frame *f, lf_ns now)
{
    if (f->src == 0 || f->src > LF_FAP_MAX_ID) {    /* our own echo, or nonsense */
        m->c.unexpected++;
        return;
    }
    switch (f->msg) {
    case LF_FAP_DATA:
        if (f->dst == 0) {
            m->c.data_rx++;
            if (m->io.deliver)
                m->io.deliver(m->io.ctx, f->src, f->data, f->len, now);
        }
        return;     /* slave-to-slave traffic is not ours */
    case LF_FAP_ID:
        if (f->dst == 0 && m->state == LF_M_ID_WAIT && m->out.len == 0 &&
            f->src == m->cur && listed(m, f->src)) {
            m->active |= 1u << f->src;
            emit_event(m, LF_FAP_EV_SLAVE_ACTIVE, f->src, now);
            id_next(m, now);
            return;
        }
        break;
    case LF_FAP_DATA_DONE:
        if (f->dst == 0 && m->state == LF_M_POLL_WAIT && m->out.len == 0 &&
            f->src == m->cur) {
            m->c.polls++;
            m->unconfirmed[f->src] = 0;
            poll_next(m, now);
            return;
        }
        break;
    default:
        break;
    }
    m->c.unexpected++;
}

void lf_fap_master_on_timer(lf_fap_master *m, lf_ns now)
{
    if (m->out.len)
        return;
    switch (m->state) {
    case LF_M_ID_WAIT:
        if (now >= m->wait_deadline) {
            m->c.id_timeouts++;
            emit_event(m, LF_FAP_EV_ID_TIMEOUT, m->cur, now);
            id_next(m, now);
        }
        break;
    case LF_M_POLL_WAIT:
        if (now >= m->wait_deadline) {
            m->c.data_done_timeouts++;
            m->active &= ~(1u << m->cur);
            m->c.tx_unconfirmed += m->unconfirmed[m->cur];
            m->unconfirmed[m->cur] = 0;
            emit_event(m, LF_FAP_EV_SLAVE_INACTIVE, m->cur, now);
            start_id_cycle(m, now);
        }
        break;
    case LF_M_IDLE:
        if ((m->listed & ~m->active) && now >= m->next_idc)
            start_id_cycle(m, now);
        break;
    case LF_M_SLOT:
        break;
    }
}

void lf_fap_master_link_reset(lf_fap_master *m, lf_ns now)
{
    if (m->out.len)
        return;                          /* not sent yet: it goes out on the new link */
    if (m->state == LF_M_POLL_WAIT && m->wait_deadline > now)
        m->wait_deadline = now;          /* timeout path: loss counted, ID cycle next */
    else if (m->state == LF_M_ID_WAIT)
        start_id_cycle(m, now);          /* ask again, from the first inactive slave */
    else if (m->state == LF_M_IDLE && (m->listed & ~m->active))
        m->next_idc = now;               /* slaves lost during the outage: query now */
}

lf_ns lf_fap_master_deadline(const lf_fap_master *m)
{
    if (m->out.len)
        return LF_NEVER;                 /* the transmission comes first */
    switch (m->state) {
    case LF_M_ID_WAIT:
    case LF_M_POLL_WAIT:
        return m->wait_deadline;
    case LF_M_IDLE:
        return (m->listed & ~m->active) ? m->next_idc : LF_NEVER;
    default:
        return LF_NEVER;
    }
}
