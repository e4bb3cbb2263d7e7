/* Closed-loop simulation with a fake clock and the REAL codec: a master
 * and slaves exchange encoded bytes over a simulated bus (random chunking,
 * 115200-baud byte times), with the vendor's real timing (1 s / 10 s /
 * 15 s run instantly on the fake clock). Slave 4 is listed but never
 * exists; slave 5 dies right after a SEND_DATA and comes back later. */
#include "sm_harness.h"
#include <stdio.h>

#define NS 6                      /* node 0 = master, 1..5 slaves */
#define BYTE_NS 86806             /* one byte at 115200 baud */

typedef struct node {
    int alive;
    lf_fap_decoder dec;
    lf_fap_master m;
    lf_fap_slave s;
    harness h;
} node;

static node N[NS];
static lf_ns now;
static lf_fap_timing T = { .idc = 15 * LF_NS_PER_S, .id_answer = LF_NS_PER_S,
                           .data_done = 15 * LF_NS_PER_S, .send_budget = 10 * LF_NS_PER_S };
static h_frame wire[20000];
static int nwire;
static int kill_after_send_data = -1;     /* slave to kill when it gets SEND_DATA */
static unsigned rng = 99;

static unsigned rnd(void)
{
    rng = rng * 1103515245u + 12345u;
    return (rng >> 16) & 0x7fff;
}

static void on_frame(void *ctx, const lf_fap_frame *f, lf_ns t)
{
    node *n = ctx;
    int idx = (int)(n - N);
    if (idx == 0) {
        lf_fap_master_on_frame(&n->m, f, t);
    } else {
        lf_fap_slave_on_frame(&n->s, f, t);
        if (f->msg == LF_FAP_SEND_DATA && f->dst == idx && idx == kill_after_send_data) {
            n->alive = 0;                 /* dies before it can answer */
            kill_after_send_data = -1;
        }
    }
}

static void start_slave(int id)
{
    node *n = &N[id];
    memset(&n->h, 0, sizeof n->h);
    lf_fap_decoder_init(&n->dec, 10 * LF_NS_PER_MS);
    lf_fap_io io = h_io(&n->h);
    lf_fap_slave_init(&n->s, (unsigned)id, &T, &io);
    n->alive = 1;
}

static const lf_fap_outbox *outbox(int i)
{
    return i == 0 ? lf_fap_master_outbox(&N[0].m) : lf_fap_slave_outbox(&N[i].s);
}

/* Put node i's outbox on the wire: every other live node hears it in chunks. */
static void transmit(int i)
{
    const lf_fap_outbox *o = outbox(i);
    uint8_t buf[LF_FAP_MAX_FRAME];
    size_t len = o->len;
    memcpy(buf, o->buf, len);
    if (nwire < 20000) {
        h_frame *w = &wire[nwire++];
        w->msg = buf[10]; w->dst = buf[11]; w->src = buf[12];
        w->len = (uint16_t)(len - LF_FAP_OVERHEAD);
        memcpy(w->data, buf + LF_FAP_HDR_LEN, w->len);
        w->t = now;
    }
    lf_ns start = now;
    size_t pos = 0;
    while (pos < len) {
        size_t k = 1 + rnd() % 64;
        if (k > len - pos)
            k = len - pos;
        lf_ns t = start + (lf_ns)(pos + k) * BYTE_NS;
        for (int j = 0; j < NS; j++)
            if (j != i && N[j].alive)
                lf_fap_decoder_feed(&N[j].dec, buf + pos, k, t, on_frame, &N[j]);
        pos += k;
    }
    now = start + (lf_ns)len * BYTE_NS + 50000;      /* + 50 us turnaround */
    if (i == 0)
        lf_fap_master_sent(&N[0].m, now);
    else if (N[i].alive)
        lf_fap_slave_sent(&N[i].s, now);
}

/* Run the bus until `until`. */
static void run_until(lf_ns until)
{
    while (now < until) {
        int busy = 0;
        for (int i = 0; i < NS; i++) {
            if (N[i].alive && outbox(i)->len) {
                transmit(i);
                busy = 1;
                break;
            }
        }
        if (busy)
            continue;
        lf_ns dl = lf_fap_master_deadline(&N[0].m);
        for (int j = 0; j < NS; j++)
            if (N[j].alive && lf_fap_decoder_deadline(&N[j].dec) < dl)
                dl = lf_fap_decoder_deadline(&N[j].dec);
        if (dl > until) {
            now = until;
            break;
        }
        if (dl > now)
            now = dl;
        for (int j = 0; j < NS; j++)
            if (N[j].alive)
                lf_fap_decoder_tick(&N[j].dec, now, on_frame, &N[j]);
        lf_fap_master_on_timer(&N[0].m, now);
    }
}

/* payload "S>D#seq" */
static void queue_msg(int from, int to, int seq)
{
    char txt[32];
    snprintf(txt, sizeof txt, "%d>%d#%d", from, to, seq);
    h_queue(&N[from].h, (unsigned)to, txt);
}

static int delivered(int at, int from, int to, int seq)
{
    char txt[32];
    int found = 0;
    snprintf(txt, sizeof txt, "%d>%d#%d", from, to, seq);
    for (int k = 0; k < N[at].h.nrx; k++)
        if (N[at].h.rx[k].src == from && N[at].h.rx[k].len == strlen(txt) &&
            memcmp(N[at].h.rx[k].data, txt, strlen(txt)) == 0)
            found++;
    return found;
}

static lf_ns first_event(int node_i, int type, unsigned id, lf_ns after)
{
    harness *h = &N[node_i].h;
    for (int k = 0; k < h->nev; k++)
        if (h->ev[k].type == type && h->ev[k].id == id && h->ev[k].t >= after)
            return h->ev[k].t;
    return -1;
}

static void test_bus_scenario(void)
{
    memset(N, 0, sizeof N);
    now = LF_NS_PER_S;
    lf_fap_decoder_init(&N[0].dec, 10 * LF_NS_PER_MS);
    lf_fap_io io = h_io(&N[0].h);
    lf_fap_master_init(&N[0].m, &T, &io, now);
    N[0].alive = 1;
    for (int id = 1; id <= 5; id++)
        if (id != 4)
            start_slave(id);
    for (unsigned id = 1; id <= 5; id++)
        CHECK_EQ(lf_fap_master_add(&N[0].m, id, now), 0);

    /* traffic: master -> each slave, slaves -> master and -> each other */
    int seq = 0;
    for (int r = 0; r < 3; r++, seq++) {
        queue_msg(0, 1, seq); queue_msg(0, 2, seq); queue_msg(0, 3, seq);
        queue_msg(1, 0, seq); queue_msg(1, 2, seq);
        queue_msg(2, 3, seq); queue_msg(3, 0, seq); queue_msg(3, 1, seq);
    }
    run_until(now + 3 * LF_NS_PER_S);

    /* the first frames: QUERY_ID 1..5 in ID order */
    int q = 0;
    for (int k = 0; k < nwire && q < 5; k++)
        if (wire[k].msg == LF_FAP_QUERY_ID)
            CHECK_EQ(wire[k].dst, ++q);
    CHECK(lf_fap_master_is_active(&N[0].m, 1));
    CHECK(lf_fap_master_is_active(&N[0].m, 5));
    CHECK(!lf_fap_master_is_active(&N[0].m, 4));
    CHECK_EQ(N[0].m.c.id_timeouts, 1);

    /* every message delivered exactly once, to the right node, from the right source */
    for (int s = 0; s < 3; s++) {
        CHECK_EQ(delivered(1, 0, 1, s), 1); CHECK_EQ(delivered(2, 0, 2, s), 1);
        CHECK_EQ(delivered(3, 0, 3, s), 1); CHECK_EQ(delivered(0, 1, 0, s), 1);
        CHECK_EQ(delivered(2, 1, 2, s), 1); CHECK_EQ(delivered(3, 2, 3, s), 1);
        CHECK_EQ(delivered(0, 3, 0, s), 1); CHECK_EQ(delivered(1, 3, 1, s), 1);
        CHECK_EQ(delivered(5, 1, 2, s), 0);   /* nobody else keeps others' data */
    }

    /* protocol order on the wire: a slave's DATA only between SEND_DATA to it
     * and its DATA_DONE; master DATA never inside a slave's turn */
    int turn = -1, order_bad = 0;
    for (int k = 0; k < nwire; k++) {
        h_frame *w = &wire[k];
        if (w->msg == LF_FAP_SEND_DATA) { if (turn != -1) order_bad++; turn = w->dst; }
        else if (w->msg == LF_FAP_DATA_DONE) { if (turn != w->src) order_bad++; turn = -1; }
        else if (w->msg == LF_FAP_DATA) { if (w->src != 0 ? turn != w->src : turn != -1) order_bad++; }
        else if (turn != -1) order_bad++;
    }
    CHECK_EQ(order_bad, 0);

    /* slave 5 dies right after its next SEND_DATA */
    kill_after_send_data = 5;
    lf_ns t_kill = now;
    run_until(now + 20 * LF_NS_PER_S);
    CHECK(!N[5].alive);
    /* the SEND_DATA it died on */
    lf_ns sd5 = -1;
    for (int k = 0; k < nwire; k++)
        if (wire[k].msg == LF_FAP_SEND_DATA && wire[k].dst == 5 && wire[k].t >= t_kill) {
            sd5 = wire[k].t;
            break;
        }
    REQUIRE(sd5 > 0);
    lf_ns sd5_end = sd5 + (lf_ns)LF_FAP_OVERHEAD * BYTE_NS + 50000;
    lf_ns inactive_at = first_event(0, LF_FAP_EV_SLAVE_INACTIVE, 5, t_kill);
    CHECK_EQ(inactive_at, sd5_end + T.data_done);      /* exactly 15 s after SEND_DATA went */
    CHECK(!lf_fap_master_is_active(&N[0].m, 5));
    CHECK_EQ(N[0].m.c.data_done_timeouts, 1);
    /* ID cycle at once: QUERY_ID to 4 and 5 right after the timeout */
    int qafter = 0;
    for (int k = 0; k < nwire; k++)
        if (wire[k].t >= inactive_at && wire[k].t < inactive_at + 3 * LF_NS_PER_S &&
            wire[k].msg == LF_FAP_QUERY_ID)
            qafter++;
    CHECK_EQ(qafter, 2);
    /* meanwhile slaves 1..3 keep being polled */
    uint64_t polls = N[0].m.c.polls;
    run_until(now + LF_NS_PER_S);
    CHECK(N[0].m.c.polls > polls);

    /* slave 5 comes back (fresh process, same ID): active after the next idc */
    lf_ns t_back = now;
    start_slave(5);
    queue_msg(5, 0, 100);
    run_until(now + 20 * LF_NS_PER_S);
    lf_ns active_again = first_event(0, LF_FAP_EV_SLAVE_ACTIVE, 5, t_back);
    CHECK(active_again > t_back);
    CHECK(active_again <= inactive_at + 2 * T.idc + LF_NS_PER_S);
    CHECK(lf_fap_master_is_active(&N[0].m, 5));
    CHECK_EQ(delivered(0, 5, 0, 100), 1);
    /* re-queries of the inactive slaves are idc apart */
    lf_ns prev = -1;
    int spacing_bad = 0, requeries = 0;
    for (int k = 0; k < nwire; k++) {
        if (wire[k].msg == LF_FAP_QUERY_ID && wire[k].dst == 4 && wire[k].t > inactive_at + LF_NS_PER_S) {
            if (prev > 0 && (wire[k].t - prev < T.idc || wire[k].t - prev > T.idc + LF_NS_PER_S))
                spacing_bad++;
            prev = wire[k].t;
            requeries++;
        }
    }
    CHECK(requeries >= 1);
    CHECK_EQ(spacing_bad, 0);
    CHECK(!lf_fap_master_is_active(&N[0].m, 4));
    /* nothing corrupted on a clean bus */
    for (int j = 0; j < NS; j++) {
        CHECK_EQ(N[j].dec.c.crc_errors, 0);
        CHECK_EQ(N[j].dec.c.framing_errors, 0);
    }
}

UNIT_MAIN(UNIT(test_bus_scenario))
