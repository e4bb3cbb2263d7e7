/* Slave state machine with a fake clock: answers only for its ID, sends
 * queued DATA in its turn within the budget, then DATA_DONE. */
#include "sm_harness.h"

#define BUDGET 100

static lf_fap_slave S;
static harness H;

static void setup(unsigned id)
{
    memset(&H, 0, sizeof H);
    lf_fap_timing t = { .send_budget = BUDGET };
    lf_fap_io io = h_io(&H);
    lf_fap_slave_init(&S, id, &t, &io);
}

static const h_frame *tx(lf_ns now)
{
    if (!lf_fap_slave_outbox(&S)->len)
        return NULL;
    h_log_outbox(&H, lf_fap_slave_outbox(&S), now);
    lf_fap_slave_sent(&S, now);
    return &H.sent[H.nsent - 1];
}

static void rx(unsigned msg, unsigned dst, unsigned src, const char *data, lf_ns now)
{
    lf_fap_frame f = h_frame_of(msg, dst, src, data);
    lf_fap_slave_on_frame(&S, &f, now);
}

static void test_answers_query_for_own_id_only(void)
{
    setup(7);
    rx(LF_FAP_QUERY_ID, 6, 0, NULL, 0);
    rx(LF_FAP_SEND_DATA, 8, 0, NULL, 0);
    CHECK(tx(0) == NULL);
    rx(LF_FAP_QUERY_ID, 7, 3, NULL, 0);       /* not from the master */
    CHECK(tx(0) == NULL);
    rx(LF_FAP_QUERY_ID, 7, 0, NULL, 1);
    const h_frame *f = tx(1);
    REQUIRE(f != NULL);
    CHECK_EQ(f->msg, LF_FAP_ID);
    CHECK_EQ(f->dst, 0);
    CHECK_EQ(f->src, 7);
    CHECK(tx(2) == NULL);
    CHECK_EQ(H.ev[0].type, LF_FAP_EV_QUERIED);
    CHECK_EQ(lf_fap_slave_deadline(&S), LF_NEVER);
}

static void test_send_data_without_data_is_done(void)
{
    setup(3);
    rx(LF_FAP_SEND_DATA, 3, 0, NULL, 10);
    const h_frame *f = tx(10);
    REQUIRE(f != NULL);
    CHECK_EQ(f->msg, LF_FAP_DATA_DONE);
    CHECK_EQ(f->src, 3);
    CHECK_EQ(f->dst, 0);
    CHECK(tx(11) == NULL);
}

static void test_turn_sends_queued_data_in_order(void)
{
    setup(3);
    h_queue(&H, 0, "to master");
    h_queue(&H, 5, "to five");
    h_queue(&H, 3, "to self");                /* dropped */
    h_queue(&H, 31, "to 31");
    rx(LF_FAP_SEND_DATA, 3, 0, NULL, 0);
    const char *want[] = { "to master", "to five", "to 31" };
    unsigned dst[] = { 0, 5, 31 };
    for (int i = 0; i < 3; i++) {
        const h_frame *f = tx(i + 1);
        REQUIRE(f != NULL);
        CHECK_EQ(f->msg, LF_FAP_DATA);
        CHECK_EQ(f->src, 3);
        CHECK_EQ(f->dst, dst[i]);
        CHECK_EQ(f->len, strlen(want[i]));
        CHECK_MEM(f->data, want[i], f->len);
    }
    const h_frame *f = tx(5);
    REQUIRE(f != NULL);
    CHECK_EQ(f->msg, LF_FAP_DATA_DONE);
    CHECK_EQ(S.c.tx_dropped, 1);
    CHECK_EQ(S.c.data_tx, 3);
}

static void test_budget_cuts_turn(void)
{
    setup(2);
    for (int i = 0; i < 5; i++)
        h_queue(&H, 0, "x");
    rx(LF_FAP_SEND_DATA, 2, 0, NULL, 1000);
    CHECK_EQ(tx(1050)->msg, LF_FAP_DATA);
    CHECK_EQ(tx(1099)->msg, LF_FAP_DATA);      /* sent within the budget */
    CHECK_EQ(tx(1100)->msg, LF_FAP_DATA);      /* ended at the budget: no more DATA */
    CHECK_EQ(tx(1100)->msg, LF_FAP_DATA_DONE);
    CHECK_EQ(H.tx_count, 2);
    CHECK_EQ(S.c.budget_cutoffs, 1);
    /* the rest goes out in the next turn */
    rx(LF_FAP_SEND_DATA, 2, 0, NULL, 2000);
    CHECK_EQ(tx(2001)->msg, LF_FAP_DATA);
    CHECK_EQ(tx(2002)->msg, LF_FAP_DATA);
    CHECK_EQ(tx(2003)->msg, LF_FAP_DATA_DONE);
}

static void test_delivers_data_for_own_id(void)
{
    setup(4);
    rx(LF_FAP_DATA, 4, 0, "from master", 0);
    rx(LF_FAP_DATA, 4, 9, "from nine", 0);
    rx(LF_FAP_DATA, 5, 9, "for five", 0);
    rx(LF_FAP_DATA, 4, 4, "own echo", 0);
    REQUIRE(H.nrx == 2);
    CHECK_EQ(H.rx[0].src, 0);
    CHECK_MEM(H.rx[0].data, "from master", 11);
    CHECK_EQ(H.rx[1].src, 9);
    CHECK_MEM(H.rx[1].data, "from nine", 9);
    CHECK(tx(0) == NULL);
}

static void test_query_during_turn_restarts(void)
{
    setup(6);
    h_queue(&H, 0, "a");
    h_queue(&H, 0, "b");
    rx(LF_FAP_SEND_DATA, 6, 0, NULL, 0);
    CHECK_EQ(tx(1)->msg, LF_FAP_DATA);
    /* the master gave up on this turn (we were too slow) and queries us
     * while 'b' waits in the outbox: 'b' still goes, then ID ends the turn */
    rx(LF_FAP_QUERY_ID, 6, 0, NULL, 2);
    const h_frame *f = tx(3);
    CHECK_EQ(f->msg, LF_FAP_DATA);
    CHECK_EQ(f->data[0], 'b');
    CHECK_EQ(tx(4)->msg, LF_FAP_ID);
    CHECK(tx(5) == NULL);
    CHECK_EQ(H.tx_count, 0);
    /* with an empty outbox the answer is immediate */
    h_queue(&H, 0, "c");
    rx(LF_FAP_SEND_DATA, 6, 0, NULL, 10);
    rx(LF_FAP_QUERY_ID, 6, 0, NULL, 10);
    CHECK_EQ(tx(11)->msg, LF_FAP_DATA);
    CHECK_EQ(tx(12)->msg, LF_FAP_ID);
}

UNIT_MAIN(UNIT(test_answers_query_for_own_id_only), UNIT(test_send_data_without_data_is_done),
          UNIT(test_turn_sends_queued_data_in_order), UNIT(test_budget_cuts_turn),
          UNIT(test_delivers_data_for_own_id), UNIT(test_query_during_turn_restarts))
