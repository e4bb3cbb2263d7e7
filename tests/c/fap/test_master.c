/* Master state machine with a fake clock: ID cycle, data cycle order,
 * DATA_DONE timeout, idc re-query, add/remove while running, budget. */
#include "sm_harness.h"

#define IDC   1000
#define IDA   10
#define DDONE 50
#define BUDGET 20

static lf_fap_master M;
static harness H;

static void setup(lf_ns now)
{
    memset(&H, 0, sizeof H);
    lf_fap_timing t = { .idc = IDC, .id_answer = IDA, .data_done = DDONE, .send_budget = BUDGET };
    lf_fap_io io = h_io(&H);
    lf_fap_master_init(&M, &t, &io, now);
}

/* Transmit the outbox at `now`: returns the frame sent (or NULL). */
static const h_frame *tx(lf_ns now)
{
    if (!lf_fap_master_outbox(&M)->len)
        return NULL;
    h_log_outbox(&H, lf_fap_master_outbox(&M), now);
    lf_fap_master_sent(&M, now);
    return &H.sent[H.nsent - 1];
}

static void rx(unsigned msg, unsigned dst, unsigned src, const char *data, lf_ns now)
{
    lf_fap_frame f = h_frame_of(msg, dst, src, data);
    lf_fap_master_on_frame(&M, &f, now);
}

#define EXPECT_TX(now, MSG, DST) do { const h_frame *f_ = tx(now); REQUIRE(f_ != NULL); \
    CHECK_EQ(f_->msg, MSG); CHECK_EQ(f_->dst, DST); CHECK_EQ(f_->src, 0); } while (0)

static void test_idle_without_slaves(void)
{
    setup(0);
    CHECK(tx(0) == NULL);
    CHECK_EQ(lf_fap_master_deadline(&M), LF_NEVER);
    CHECK_EQ(lf_fap_master_add(&M, 0, 0), -EINVAL);
    CHECK_EQ(lf_fap_master_add(&M, 32, 0), -EINVAL);
    CHECK_EQ(lf_fap_master_remove(&M, 3, 0), -ENOENT);
}

static void test_id_cycle_then_data_cycle(void)
{
    setup(0);
    CHECK_EQ(lf_fap_master_add(&M, 1, 0), 0);
    CHECK_EQ(lf_fap_master_add(&M, 1, 0), -EEXIST);
    /* the add started an ID cycle at once; adds before the frame goes are included */
    CHECK_EQ(lf_fap_master_add(&M, 3, 0), 0);
    CHECK_EQ(lf_fap_master_add(&M, 2, 0), 0);
    EXPECT_TX(1, LF_FAP_QUERY_ID, 1);
    CHECK_EQ(lf_fap_master_deadline(&M), 1 + IDA);
    rx(LF_FAP_ID, 0, 1, NULL, 5);
    CHECK(lf_fap_master_is_active(&M, 1));
    REQUIRE(H.nev == 1);
    CHECK_EQ(H.ev[0].type, LF_FAP_EV_SLAVE_ACTIVE);
    CHECK_EQ(H.ev[0].id, 1);
    EXPECT_TX(6, LF_FAP_QUERY_ID, 2);
    rx(LF_FAP_ID, 0, 2, NULL, 7);
    EXPECT_TX(8, LF_FAP_QUERY_ID, 3);
    rx(LF_FAP_ID, 0, 3, NULL, 9);
    CHECK_EQ(M.c.id_cycles, 1);
    /* data cycle: SEND_DATA 1, 2, 3 in order */
    for (unsigned id = 1; id <= 3; id++) {
        EXPECT_TX(10 * id, LF_FAP_SEND_DATA, id);
        CHECK_EQ(lf_fap_master_deadline(&M), 10 * id + DDONE);
        rx(LF_FAP_DATA_DONE, 0, id, NULL, 10 * id + 1);
    }
    CHECK_EQ(M.c.cycles, 1);
    CHECK_EQ(M.c.polls, 3);
    /* back to back: the next cycle starts at once */
    EXPECT_TX(40, LF_FAP_SEND_DATA, 1);
}

static void test_id_timeout_and_idc_requery(void)
{
    setup(0);
    lf_fap_master_add(&M, 1, 0);
    lf_fap_master_add(&M, 2, 0);           /* never answers */
    EXPECT_TX(0, LF_FAP_QUERY_ID, 1);
    rx(LF_FAP_ID, 0, 1, NULL, 1);
    EXPECT_TX(2, LF_FAP_QUERY_ID, 2);
    /* the answer window: nothing one tick early, timeout exactly at the deadline */
    lf_fap_master_on_timer(&M, 2 + IDA - 1);
    CHECK(lf_fap_master_outbox(&M)->len == 0);
    lf_fap_master_on_timer(&M, 2 + IDA);
    CHECK_EQ(M.c.id_timeouts, 1);
    CHECK(!lf_fap_master_is_active(&M, 2));
    CHECK_EQ(H.ev[H.nev - 1].type, LF_FAP_EV_ID_TIMEOUT);
    /* data cycles poll only slave 1, until idc has passed since the ID cycle began */
    lf_ns t = 20;
    int requeried = 0;
    while (t < 3 * IDC) {
        const h_frame *f = tx(t);
        REQUIRE(f != NULL);
        if (f->msg == LF_FAP_QUERY_ID) {
            CHECK_EQ(f->dst, 2);
            requeried = 1;
            break;
        }
        CHECK_EQ(f->msg, LF_FAP_SEND_DATA);
        CHECK_EQ(f->dst, 1);
        t += 7;
        rx(LF_FAP_DATA_DONE, 0, 1, NULL, t);
    }
    CHECK(requeried);
    CHECK(t >= IDC);              /* not before idc after the first ID cycle (began at 0) */
    CHECK(t < IDC + 10);          /* and right after the data cycle in progress */
    /* the slave answers now: it joins the data cycle */
    rx(LF_FAP_ID, 0, 2, NULL, t + 1);
    CHECK(lf_fap_master_is_active(&M, 2));
    EXPECT_TX(t + 2, LF_FAP_SEND_DATA, 1);
    rx(LF_FAP_DATA_DONE, 0, 1, NULL, t + 3);
    EXPECT_TX(t + 4, LF_FAP_SEND_DATA, 2);
}

static void test_data_done_timeout_marks_inactive(void)
{
    setup(0);
    lf_fap_master_add(&M, 4, 0);
    lf_fap_master_add(&M, 5, 0);
    EXPECT_TX(0, LF_FAP_QUERY_ID, 4);
    rx(LF_FAP_ID, 0, 4, NULL, 1);
    EXPECT_TX(1, LF_FAP_QUERY_ID, 5);
    rx(LF_FAP_ID, 0, 5, NULL, 2);
    EXPECT_TX(100, LF_FAP_SEND_DATA, 4);
    /* slave 4 sends data to slave 5 and to the master, then dies */
    rx(LF_FAP_DATA, 5, 4, "to five", 101);
    rx(LF_FAP_DATA, 0, 4, "to master", 102);
    CHECK_EQ(H.nrx, 1);
    CHECK_MEM(H.rx[0].data, "to master", 9);
    CHECK_EQ(H.rx[0].src, 4);
    lf_fap_master_on_timer(&M, 100 + DDONE - 1);
    CHECK(lf_fap_master_is_active(&M, 4));
    lf_fap_master_on_timer(&M, 100 + DDONE);
    CHECK(!lf_fap_master_is_active(&M, 4));
    CHECK_EQ(M.c.data_done_timeouts, 1);
    CHECK_EQ(H.ev[H.nev - 1].type, LF_FAP_EV_SLAVE_INACTIVE);
    CHECK_EQ(H.ev[H.nev - 1].id, 4);
    CHECK_EQ(H.ev[H.nev - 1].t, 100 + DDONE);
    /* an ID cycle at once, for the inactive slave only */
    EXPECT_TX(100 + DDONE, LF_FAP_QUERY_ID, 4);
    /* a late DATA_DONE from 4 is ignored */
    rx(LF_FAP_DATA_DONE, 0, 4, NULL, 100 + DDONE + 1);
    CHECK(!lf_fap_master_is_active(&M, 4));
    lf_fap_master_on_timer(&M, 100 + DDONE + IDA);
    EXPECT_TX(200, LF_FAP_SEND_DATA, 5);
    /* a late ID from 4 (outside its window) does not activate it */
    rx(LF_FAP_ID, 0, 4, NULL, 201);
    CHECK(!lf_fap_master_is_active(&M, 4));
    CHECK_EQ(M.c.unexpected, 2);
}

static void test_master_slot_first_and_budget(void)
{
    setup(0);
    lf_fap_master_add(&M, 1, 0);
    EXPECT_TX(0, LF_FAP_QUERY_ID, 1);
    h_queue(&H, 1, "a");
    h_queue(&H, 2, "b");
    h_queue(&H, 0, "bad");                 /* master to itself: dropped */
    h_queue(&H, 1, "c");
    h_queue(&H, 1, "d");
    rx(LF_FAP_ID, 0, 1, NULL, 1);
    /* slot: DATA frames before any SEND_DATA */
    const h_frame *f = tx(2);
    REQUIRE(f && f->msg == LF_FAP_DATA);
    CHECK_EQ(f->dst, 1);
    CHECK_EQ(f->data[0], 'a');
    f = tx(3);
    REQUIRE(f && f->msg == LF_FAP_DATA);
    CHECK_EQ(f->dst, 2);
    /* 'c' finishes exactly when the budget (20, from t=1) is spent */
    f = tx(1 + BUDGET);
    REQUIRE(f && f->msg == LF_FAP_DATA);
    CHECK_EQ(f->data[0], 'c');
    CHECK_EQ(M.c.tx_dropped, 1);
    CHECK_EQ(M.c.budget_cutoffs, 1);
    /* so the slot ends: 'd' waits for the next cycle */
    f = tx(22);
    REQUIRE(f != NULL);
    CHECK_EQ(f->msg, LF_FAP_SEND_DATA);
    CHECK_EQ(H.tx_count, 1);
    rx(LF_FAP_DATA_DONE, 0, 1, NULL, 30);
    f = tx(31);
    REQUIRE(f && f->msg == LF_FAP_DATA);
    CHECK_EQ(f->data[0], 'd');
}

static void test_idle_master_sends_queued_data(void)
{
    setup(0);
    h_queue(&H, 7, "x");
    lf_fap_master_tx_queued(&M, 0);
    const h_frame *f = tx(0);
    REQUIRE(f && f->msg == LF_FAP_DATA);
    CHECK_EQ(f->dst, 7);
    CHECK(tx(1) == NULL);
    CHECK_EQ(lf_fap_master_deadline(&M), LF_NEVER);
}

static void test_idle_until_idc(void)
{
    setup(0);
    lf_fap_master_add(&M, 9, 0);
    EXPECT_TX(0, LF_FAP_QUERY_ID, 9);
    lf_fap_master_on_timer(&M, IDA);
    CHECK(tx(IDA) == NULL);                       /* nobody active: idle */
    CHECK_EQ(lf_fap_master_deadline(&M), IDC);    /* next ID cycle idc after the first began */
    lf_fap_master_on_timer(&M, IDC - 1);
    CHECK(tx(IDC - 1) == NULL);
    lf_fap_master_on_timer(&M, IDC);
    EXPECT_TX(IDC, LF_FAP_QUERY_ID, 9);
}

static void test_add_remove_while_running(void)
{
    setup(0);
    lf_fap_master_add(&M, 1, 0);
    lf_fap_master_add(&M, 2, 0);
    EXPECT_TX(0, LF_FAP_QUERY_ID, 1);
    rx(LF_FAP_ID, 0, 1, NULL, 1);
    EXPECT_TX(1, LF_FAP_QUERY_ID, 2);
    rx(LF_FAP_ID, 0, 2, NULL, 2);
    EXPECT_TX(3, LF_FAP_SEND_DATA, 1);
    /* added during the data cycle: queried when this cycle ends */
    CHECK_EQ(lf_fap_master_add(&M, 6, 4), 0);
    CHECK(tx(4) == NULL);
    rx(LF_FAP_DATA_DONE, 0, 1, NULL, 5);
    EXPECT_TX(5, LF_FAP_SEND_DATA, 2);
    /* removing the slave being polled moves on at once (cycle ends -> ID cycle for 6) */
    CHECK_EQ(lf_fap_master_remove(&M, 2, 6), 0);
    EXPECT_TX(6, LF_FAP_QUERY_ID, 6);
    /* removing the queried slave skips it too */
    CHECK_EQ(lf_fap_master_remove(&M, 6, 7), 0);
    EXPECT_TX(7, LF_FAP_SEND_DATA, 1);
    CHECK_EQ(M.listed, 1u << 1);
    /* a removed slave is never polled again */
    rx(LF_FAP_DATA_DONE, 0, 1, NULL, 8);
    EXPECT_TX(8, LF_FAP_SEND_DATA, 1);
    /* re-added: fresh and inactive until it answers */
    CHECK_EQ(lf_fap_master_add(&M, 2, 9), 0);
    CHECK(!lf_fap_master_is_active(&M, 2));
}

static void test_frames_not_for_master_ignored(void)
{
    setup(0);
    rx(LF_FAP_DATA, 0, 0, "echo", 0);         /* our own src */
    rx(LF_FAP_DATA, 3, 2, "s2s", 0);          /* slave to slave */
    rx(LF_FAP_DATA, 0, 40, "bad src", 0);
    CHECK_EQ(H.nrx, 0);
    rx(LF_FAP_DATA, 0, 2, "ok", 0);
    CHECK_EQ(H.nrx, 1);
    CHECK_EQ(M.c.data_rx, 1);
}

/* Added during an ID cycle, below the slave being queried: queried right
 * after that cycle, not idc later. */
static void test_add_during_id_cycle_below_cursor(void)
{
    setup(0);
    lf_fap_master_add(&M, 5, 0);
    EXPECT_TX(0, LF_FAP_QUERY_ID, 5);
    CHECK_EQ(lf_fap_master_add(&M, 2, 1), 0);
    lf_fap_master_on_timer(&M, IDA);          /* 5 never answers */
    EXPECT_TX(IDA, LF_FAP_QUERY_ID, 2);
    rx(LF_FAP_ID, 0, 2, NULL, IDA + 1);
    CHECK(lf_fap_master_is_active(&M, 2));
    /* that ID cycle goes on to every inactive slave, 5 included */
    EXPECT_TX(IDA + 2, LF_FAP_QUERY_ID, 5);
    lf_fap_master_on_timer(&M, IDA + 2 + IDA);
    EXPECT_TX(IDA + 2 + IDA, LF_FAP_SEND_DATA, 2);
}

/* The port came back after a network server's restart: no answer awaited
 * then will come. A DATA_DONE wait ends at once (the slave is marked
 * inactive, counted, and queried again), an ID wait starts the ID cycle
 * over, an idle master with inactive slaves queries them now, and a frame
 * not sent yet is left alone. */
static void test_link_reset(void)
{
    setup(0);
    CHECK_EQ(lf_fap_master_add(&M, 1, 0), 0);
    EXPECT_TX(1, LF_FAP_QUERY_ID, 1);
    rx(LF_FAP_ID, 0, 1, NULL, 2);
    EXPECT_TX(3, LF_FAP_SEND_DATA, 1);
    CHECK_EQ(lf_fap_master_deadline(&M), 3 + DDONE);
    lf_fap_master_link_reset(&M, 5);              /* DATA_DONE will not come */
    CHECK_EQ(lf_fap_master_deadline(&M), 5);
    lf_fap_master_on_timer(&M, 5);
    CHECK_EQ(M.c.data_done_timeouts, 1);
    CHECK(!lf_fap_master_is_active(&M, 1));
    lf_fap_master_link_reset(&M, 5);              /* QUERY_ID in the outbox: left alone */
    EXPECT_TX(6, LF_FAP_QUERY_ID, 1);
    lf_fap_master_link_reset(&M, 7);              /* its answer died: ask again */
    EXPECT_TX(7, LF_FAP_QUERY_ID, 1);
    CHECK_EQ(M.c.id_timeouts, 0);
    lf_fap_master_on_timer(&M, 7 + IDA);          /* no answer now either */
    CHECK_EQ(M.c.id_timeouts, 1);
    CHECK(tx(7 + IDA) == NULL);                   /* idle until the next ID cycle ... */
    CHECK_EQ(lf_fap_master_deadline(&M), 7 + IDC);
    lf_fap_master_link_reset(&M, 30);             /* ... unless the link came back */
    CHECK_EQ(lf_fap_master_deadline(&M), 30);
    lf_fap_master_on_timer(&M, 30);
    EXPECT_TX(31, LF_FAP_QUERY_ID, 1);
}

UNIT_MAIN(UNIT(test_link_reset), UNIT(test_idle_without_slaves), UNIT(test_id_cycle_then_data_cycle),
          UNIT(test_id_timeout_and_idc_requery), UNIT(test_data_done_timeout_marks_inactive),
          UNIT(test_master_slot_first_and_budget), UNIT(test_idle_master_sends_queued_data),
          UNIT(test_idle_until_idc), UNIT(test_add_remove_while_running),
          UNIT(test_frames_not_for_master_ignored),
          UNIT(test_add_during_id_cycle_below_cursor))
