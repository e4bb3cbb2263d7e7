/* The read planner (port/rx_plan.h) on a fake clock: no port, no fd, no
 * sleep. A test moves `clk` itself and hands the planner what a read
 * "brought", then checks the action (sleep until / watch until /
 * complete), its reason and time, and the link belief, exactly: each
 * rule of the blocking reads (exec async, mikroC) and of the FAP engine. */
#include "port/rx_plan.h"
#include "unit.h"

#define BAUD 115200
#define CT ((lf_ns)(10LL * LF_NS_PER_S / BAUD))   /* 86.8 us */
#define US LF_NS_PER_US
#define MARGIN (150 * US)                         /* max(ct, 150 us) at 115200 */

static lf_ns clk;                                 /* the fake clock */

static lf_rx_action piece(lf_rx_plan *pl, size_t n, size_t missing, int first, lf_ns slept_to,
                          lf_ns deadline)
{
    lf_rx_piece in = { .n = n, .missing = missing, .first = first, .now = clk,
                       .slept_to = slept_to, .deadline = deadline };
    return lf_rx_plan_piece(pl, &in);
}

/* a is evaluated once: a planner call changes the plan */
#define CHECK_ACT(a, kind, reason) do { lf_rx_action a_ = (a); CHECK_EQ(a_.act, kind); \
                                        CHECK_EQ(a_.why, reason); } while (0)

static void test_hold_arithmetic(void)
{
    CHECK_EQ(lf_rx_hold_ct_ns(CT, 1), 0);                 /* the last byte: on the fd */
    CHECK_EQ(lf_rx_hold_ct_ns(CT, 3), 0);                 /* 174 - 150 us: not worth a timer */
    CHECK_EQ(lf_rx_hold_ct_ns(CT, 15), 14 * CT - MARGIN);
    CHECK_EQ(lf_rx_hold_ns(9600, 15), 13 * lf_char_time_ns(9600));   /* margin: 1 char */
    CHECK_EQ(lf_rx_hold_ns(0, 15), 0);
    CHECK(lf_rx_at_baud(5 * CT, CT, 5));
    CHECK(lf_rx_at_baud(5 * CT * 7 / 10 + 1, CT, 5));         /* 30 % early: still the baud */
    CHECK(!lf_rx_at_baud(5 * CT / 2, CT, 5));
    CHECK_EQ(lf_rx_rest_deadline(CT, 4, 1000, LF_NEVER), 1000 + 4 * CT);
    CHECK_EQ(lf_rx_rest_deadline(CT, 4, 1000, 2000), 2000);
}

/* No belief yet: the first piece is watched for its successor (the pace),
 * the second at the baud sets the belief and holds all but the last byte
 * less the margin; the read at the hold's end leaves the last byte to the
 * fd (LAST), the next completes. */
static void test_observe_then_hold(void)
{
    lf_rx_link link = {0};
    lf_rx_plan pl;
    lf_rx_plan_init(&pl, BAUD, &link, 0);
    clk = 1000 * US;
    lf_ns dl = clk + 100 * CT;
    lf_rx_action a = piece(&pl, 3, 20, 1, 0, dl);
    CHECK_ACT(a, LF_RX_WATCH_UNTIL, LF_RX_OBSERVE);
    CHECK_EQ(a.until, dl);
    clk += 2 * CT;                                        /* 2 bytes in 2 characters */
    a = piece(&pl, 2, 18, 0, 0, dl);
    CHECK_EQ(link.at_baud, 1);
    CHECK_ACT(a, LF_RX_SLEEP_UNTIL, LF_RX_HOLD);
    CHECK_EQ(a.until, clk + 17 * CT - MARGIN);
    lf_ns due = a.until;
    clk = due + 5 * US;
    a = piece(&pl, 16, 2, 0, due, dl);
    CHECK_ACT(a, LF_RX_WATCH_UNTIL, LF_RX_LAST);          /* 2 left: no timer for them */
    clk += CT;
    a = piece(&pl, 2, 0, 0, 0, dl);
    CHECK_ACT(a, LF_RX_COMPLETE, LF_RX_DONE);
    CHECK_EQ(pl.t_last, 0);
}

/* A link 10x faster than the baud: the belief is cleared and the hold
 * follows the observed pace; a slower link is held at the baud's pace (a
 * byte is never read later than it can come). */
static void test_observed_pace(void)
{
    lf_rx_link link = {1};
    lf_rx_plan pl;
    lf_rx_plan_init(&pl, BAUD, NULL, 0);                  /* no belief kept */
    clk = 5000 * US;
    CHECK_ACT(piece(&pl, 3, 100, 1, 0, LF_NEVER), LF_RX_WATCH_UNTIL, LF_RX_OBSERVE);
    clk += 50 * US;                                       /* 5 bytes in 50 us */
    lf_rx_action a = piece(&pl, 5, 100, 0, 0, LF_NEVER);
    CHECK_EQ(a.until, clk + 99 * 10 * US - MARGIN);
    lf_rx_plan_init(&pl, BAUD, &link, 0);
    link.at_baud = 0;
    piece(&pl, 3, 100, 1, 0, LF_NEVER);
    clk += 50 * US;
    a = piece(&pl, 5, 100, 0, 0, LF_NEVER);
    CHECK_EQ(link.at_baud, 0);                            /* faster than the baud */
    clk += 3 * CT;                                        /* 1 byte in 3 characters */
    a = piece(&pl, 1, 100, 0, 0, LF_NEVER);
    CHECK_EQ(link.at_baud, 1);
    CHECK_EQ(a.until, clk + 99 * CT - MARGIN);            /* the baud's pace, not 3x */
    /* baud unknown: the observation alone */
    lf_rx_plan_init(&pl, 0, &link, 0);
    piece(&pl, 3, 100, 1, 0, LF_NEVER);
    clk += 200 * US;
    a = piece(&pl, 2, 100, 0, 0, LF_NEVER);
    CHECK_EQ(a.until, clk + 99 * 100 * US - MARGIN);
}

/* The belief set: the first piece holds at once at the baud's pace
 * (HOLD_KEPT). Complete at a wake within a character time of the hold's
 * end clears it; a wake later than that keeps it (the machine was late,
 * not the link fast). */
static void test_kept_belief(void)
{
    lf_rx_link link = {1};
    lf_rx_plan pl;
    lf_rx_plan_init(&pl, BAUD, &link, 0);
    clk = 9000 * US;
    lf_rx_action a = piece(&pl, 2, 14, 1, 0, LF_NEVER);
    CHECK_ACT(a, LF_RX_SLEEP_UNTIL, LF_RX_HOLD_KEPT);
    CHECK_EQ(a.until, clk + 13 * CT - MARGIN);
    lf_ns due = a.until;
    clk = due + 2 * CT;                                   /* woke 2 characters late */
    a = piece(&pl, 14, 0, 0, due, LF_NEVER);
    CHECK_ACT(a, LF_RX_COMPLETE, LF_RX_DONE);
    CHECK_EQ(link.at_baud, 1);
    a = piece(&pl, 2, 14, 1, 0, LF_NEVER);
    due = a.until;
    clk = due + CT / 2;                                   /* on time, and all in */
    piece(&pl, 14, 0, 0, due, LF_NEVER);
    CHECK_EQ(link.at_baud, 0);
    /* the next frame observes again */
    CHECK_ACT(piece(&pl, 2, 14, 1, 0, LF_NEVER), LF_RX_WATCH_UNTIL, LF_RX_OBSERVE);
}

/* Which on-time complete hold clears the belief: the blocking reads, only
 * one taken on it; the FAP engine (any_hold_clears), any. */
static void test_which_hold_clears(void)
{
    for (int any = 0; any <= 1; any++) {
        lf_rx_link link = {0};
        lf_rx_plan pl;
        lf_rx_plan_init(&pl, BAUD, &link, any);
        clk = 20000 * US;
        piece(&pl, 2, 30, 1, 0, LF_NEVER);
        clk += 2 * CT;
        lf_rx_action a = piece(&pl, 2, 28, 0, 0, LF_NEVER);   /* at the baud: set */
        CHECK_EQ(link.at_baud, 1);
        lf_ns due = a.until;
        clk = due;
        piece(&pl, 28, 0, 0, due, LF_NEVER);                  /* an observed hold, complete */
        CHECK_EQ(link.at_baud, any ? 0 : 1);
    }
}

/* A hold never ends past the reader's deadline; the read at a capped
 * hold's end completes with what is in (DEADLINE), a frame still short. */
static void test_deadline_caps(void)
{
    lf_rx_link link = {1};
    lf_rx_plan pl;
    lf_rx_plan_init(&pl, BAUD, &link, 0);
    clk = 30000 * US;
    lf_ns dl = clk + 5 * CT;
    lf_rx_action a = piece(&pl, 2, 20, 1, 0, dl);
    CHECK_ACT(a, LF_RX_SLEEP_UNTIL, LF_RX_HOLD_KEPT);
    CHECK_EQ(a.until, dl);
    clk = dl;
    a = piece(&pl, 5, 15, 0, dl, dl);
    CHECK_ACT(a, LF_RX_COMPLETE, LF_RX_DEADLINE);
    /* a short frame at 1 Mbaud: no hold is worth its timer */
    lf_rx_plan_init(&pl, 1000000, &link, 0);
    link.at_baud = 1;
    CHECK_ACT(piece(&pl, 2, 14, 1, 0, LF_NEVER), LF_RX_WATCH_UNTIL, LF_RX_LAST);
}

/* exec async / mikroC: the reply slept for until the request's end plus
 * its expected wire time, on a link believed at the baud only. */
static void test_expected_reply(void)
{
    lf_rx_link link = {1};
    lf_rx_plan pl;
    lf_rx_plan_init(&pl, BAUD, &link, 0);
    clk = 50000 * US;
    lf_ns nb = clk + 16 * CT, dl = clk + 100 * CT;
    lf_rx_action a = lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, 16, nb, clk, dl);
    CHECK_ACT(a, LF_RX_SLEEP_UNTIL, LF_RX_REPLY);
    CHECK_EQ(a.until, nb);
    CHECK_EQ(pl.stage, LF_RX_REPLY_ASLEEP);
    /* 15 of 16 at the wake: the rest bounded by its wire time */
    clk = nb + 10 * US;
    lf_rx_reply_read r = { .got = 15, .want = 16, .now = clk, .slept_to = nb, .deadline = dl };
    a = lf_rx_plan_reply_read(&pl, LF_RX_REPLY_EXPECTED, &r);
    CHECK_ACT(a, LF_RX_WATCH_UNTIL, LF_RX_REPLY_REST);
    CHECK_EQ(a.until, clk + CT);
    CHECK_EQ(pl.stage, LF_RX_REPLY_NONE);
    /* nothing yet: the fd, until the deadline */
    lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, 16, nb, clk - 20 * CT, dl);
    r.got = 0;
    a = lf_rx_plan_reply_read(&pl, LF_RX_REPLY_EXPECTED, &r);
    CHECK_ACT(a, LF_RX_WATCH_UNTIL, LF_RX_OBSERVE);
    CHECK_EQ(a.until, dl);
    /* complete at a late wake: kept; at an on-time wake: the link is faster */
    lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, 16, nb, clk - 20 * CT, dl);
    r = (lf_rx_reply_read){ .got = 16, .want = 16, .now = nb + 2 * CT, .slept_to = nb, .deadline = dl };
    CHECK_ACT(lf_rx_plan_reply_read(&pl, LF_RX_REPLY_EXPECTED, &r), LF_RX_COMPLETE, LF_RX_DONE);
    CHECK_EQ(link.at_baud, 1);
    lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, 16, nb, clk - 20 * CT, dl);
    r.now = nb + CT;
    lf_rx_plan_reply_read(&pl, LF_RX_REPLY_EXPECTED, &r);
    CHECK_EQ(link.at_baud, 0);
    /* no belief: no sleep */
    CHECK_ACT(lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, 16, nb, clk - 20 * CT, dl),
              LF_RX_WATCH_UNTIL, LF_RX_OBSERVE);
    link.at_baud = 1;
    /* not_before already past, the deadline past, a reply too short for a hold */
    CHECK_EQ(lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, 16, nb, nb, dl).act, LF_RX_WATCH_UNTIL);
    CHECK_EQ(lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, 16, nb, dl, dl).act, LF_RX_WATCH_UNTIL);
    CHECK_EQ(lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, 3, nb, clk - 20 * CT, dl).act,
             LF_RX_WATCH_UNTIL);
    /* the deadline first: the sleep ends there, what is in is the answer */
    a = lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, 16, dl + CT, clk - 20 * CT, dl);
    CHECK_EQ(a.until, dl);
    r = (lf_rx_reply_read){ .got = 4, .want = 16, .now = dl, .slept_to = dl, .deadline = dl };
    CHECK_ACT(lf_rx_plan_reply_read(&pl, LF_RX_REPLY_EXPECTED, &r), LF_RX_COMPLETE,
              LF_RX_DEADLINE);
}

/* FAP: the predictor's time (0: watch the port); at the wake, a reply not
 * in is held for all but its last byte at the baud's pace, no margin
 * (stage HOLD), never past the gap deadline; the rest's read watches. A
 * frame sent meanwhile voids the sleep. */
static void test_predicted_reply(void)
{
    lf_rx_link link = {0};
    lf_rx_plan pl;
    lf_rx_plan_init(&pl, BAUD, &link, 1);
    clk = 70000 * US;
    lf_ns wait_dl = clk + 100 * CT;
    CHECK_ACT(lf_rx_plan_reply(&pl, LF_RX_REPLY_PREDICTED, 15, 0, clk, wait_dl),
              LF_RX_WATCH_UNTIL, LF_RX_OBSERVE);
    CHECK_EQ(pl.stage, LF_RX_REPLY_NONE);
    lf_ns at = clk + 20 * CT;
    lf_rx_action a = lf_rx_plan_reply(&pl, LF_RX_REPLY_PREDICTED, 15, at, clk, wait_dl);
    CHECK_ACT(a, LF_RX_SLEEP_UNTIL, LF_RX_REPLY);
    CHECK_EQ(a.until, at);
    CHECK_EQ(pl.stage, LF_RX_REPLY_ASLEEP);
    /* nothing came: the whole reply but its last byte */
    clk = at;
    lf_rx_reply_read r = { .got = 0, .want = 15, .now = clk, .slept_to = at, .deadline = LF_NEVER };
    a = lf_rx_plan_reply_read(&pl, LF_RX_REPLY_PREDICTED, &r);
    CHECK_ACT(a, LF_RX_SLEEP_UNTIL, LF_RX_REPLY_REST);
    CHECK_EQ(a.until, clk + 14 * CT);
    CHECK_EQ(pl.stage, LF_RX_REPLY_HOLD);
    /* the rest's read: whatever is missing is the port's */
    r = (lf_rx_reply_read){ .got = 14, .want = 15, .missing = 1, .now = a.until };
    CHECK_ACT(lf_rx_plan_reply_read(&pl, LF_RX_REPLY_PREDICTED, &r), LF_RX_WATCH_UNTIL, LF_RX_LAST);
    /* 5 missing at the wake: held, capped by the gap deadline */
    lf_rx_plan_reply(&pl, LF_RX_REPLY_PREDICTED, 15, at, clk, wait_dl);
    r = (lf_rx_reply_read){ .got = 10, .want = 15, .missing = 5, .now = clk, .deadline = clk + 2 * CT };
    a = lf_rx_plan_reply_read(&pl, LF_RX_REPLY_PREDICTED, &r);
    CHECK_EQ(a.until, clk + 2 * CT);
    /* complete, or one byte short: the port */
    lf_rx_plan_reply(&pl, LF_RX_REPLY_PREDICTED, 15, at, clk, wait_dl);
    r = (lf_rx_reply_read){ .got = 15, .want = 15, .done = 1, .now = clk, .deadline = LF_NEVER };
    CHECK_ACT(lf_rx_plan_reply_read(&pl, LF_RX_REPLY_PREDICTED, &r), LF_RX_WATCH_UNTIL, LF_RX_DONE);
    lf_rx_plan_reply(&pl, LF_RX_REPLY_PREDICTED, 15, at, clk, wait_dl);
    r = (lf_rx_reply_read){ .got = 14, .want = 15, .missing = 1, .now = clk, .deadline = LF_NEVER };
    CHECK_ACT(lf_rx_plan_reply_read(&pl, LF_RX_REPLY_PREDICTED, &r), LF_RX_WATCH_UNTIL, LF_RX_LAST);
    /* capped at the reply timeout */
    CHECK_EQ(lf_rx_plan_reply(&pl, LF_RX_REPLY_PREDICTED, 15, wait_dl + CT, clk, wait_dl).until,
             wait_dl);
    /* a frame sent while asleep for the reply: void */
    CHECK_EQ(lf_rx_plan_sent(&pl, 0), 1);
    CHECK_EQ(pl.stage, LF_RX_REPLY_NONE);
    CHECK_EQ(lf_rx_plan_sent(&pl, 0), 0);
    /* while holding for a rest: void only when its frame is gone */
    pl.stage = LF_RX_REPLY_HOLD;
    CHECK_EQ(lf_rx_plan_sent(&pl, 3), 0);
    CHECK_EQ(pl.stage, LF_RX_REPLY_HOLD);
    CHECK_EQ(lf_rx_plan_sent(&pl, 0), 1);
    CHECK_EQ(link.at_baud, 0);                            /* the reply wait leaves the belief */
}

UNIT_MAIN(UNIT(test_hold_arithmetic), UNIT(test_observe_then_hold), UNIT(test_observed_pace),
          UNIT(test_kept_belief), UNIT(test_which_hold_clears), UNIT(test_deadline_caps),
          UNIT(test_expected_reply), UNIT(test_predicted_reply))
