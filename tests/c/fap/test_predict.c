/* The master's predicted reply read (fap/reply_predict.h): the learning
 * rules on their own (sans-I/O, exact), then a real master and slave on
 * the paced virtual bus, counting the master engine thread's wake-ups per
 * poll cycle (a count, not a time). */
#include "bus_util.h"
#include "fap/fapx_internal.h"
#include "fap/reply_predict.h"
#include <dirent.h>
#include <pthread.h>
#include <unistd.h>

#define BAUD 115200
#define CT ((lf_ns)(10LL * LF_NS_PER_S / BAUD))
#define WIRE (LF_FAP_OVERHEAD * CT)

/* LF_REPLY_PREDICT_TIGHT_N observations of the same turnaround: the
 * slave's turnaround is tight, predictions start. */
static void learn(lf_reply_predict *p, unsigned id, lf_ns ta)
{
    for (int i = 0; i < LF_REPLY_PREDICT_TIGHT_N; i++)
        lf_reply_predict_observed(p, id, 0, ta + WIRE);
}

static void test_no_prediction_before_a_paced_reply(void)
{
    lf_reply_predict p;
    lf_reply_predict_init(&p, BAUD, 1);
    CHECK_EQ(lf_reply_predict_when(&p, 1, 1000000), 0);      /* nothing learned */
    /* a reply complete 50 us after our frame's end: faster than its own
     * 15 bytes at the baud (an unpaced pty): still no prediction */
    lf_reply_predict_observed(&p, 1, 1000000, 1000000 + 50000);
    CHECK_EQ(lf_reply_predict_when(&p, 1, 2000000), 0);
    /* at the baud, with a 200 us turnaround: sent_end + 200 us + wire,
     * once LF_REPLY_PREDICT_TIGHT_N replies came so */
    for (int i = 0; i < LF_REPLY_PREDICT_TIGHT_N; i++) {
        CHECK_EQ(lf_reply_predict_when(&p, 1, 5000000), 0);
        lf_reply_predict_observed(&p, 1, 1000000, 1000000 + 200000 + WIRE);
    }
    CHECK_EQ(lf_reply_predict_when(&p, 1, 5000000), 5000000 + 200000 + WIRE);
    CHECK_EQ(lf_reply_predict_when(&p, 2, 5000000), 0);      /* per slave */
    CHECK_EQ(lf_reply_predict_when(&p, 0, 5000000), 0);
    CHECK_EQ(lf_reply_predict_when(&p, 32, 5000000), 0);
    /* a network transport, or an unknown baud: never */
    lf_reply_predict_init(&p, BAUD, 0);
    learn(&p, 1, 200000);
    CHECK_EQ(lf_reply_predict_when(&p, 1, 5000000), 0);
    lf_reply_predict_init(&p, 0, 1);
    learn(&p, 1, 200000);
    CHECK_EQ(lf_reply_predict_when(&p, 1, 5000000), 0);
}

static void test_learning_steps(void)
{
    lf_reply_predict p;
    lf_reply_predict_init(&p, BAUD, 1);
    learn(&p, 1, 400000);
    CHECK_EQ(p.ta[1], 400000);
    /* a later observation only lowers it (an observation includes the
     * engine's wake-up latency: the smallest is the best bound) */
    lf_reply_predict_observed(&p, 1, 0, 900000 + WIRE);
    CHECK_EQ(p.ta[1], 400000);
    lf_reply_predict_observed(&p, 1, 0, 300000 + WIRE);
    CHECK_EQ(p.ta[1], 300000);
    /* complete: down a step (1/16 of 300 us: more than an eighth of a character time) */
    lf_reply_predict_outcome(&p, 1, 0);
    CHECK_EQ(p.ta[1], 300000 - 300000 / 16);
    /* missing bytes: up one step, however late the reply was */
    lf_reply_predict_outcome(&p, 1, LF_FAP_OVERHEAD);
    CHECK_EQ(p.ta[1], 281250 + 281250 / 16);
    /* a small estimate moves by an eighth of a character time */
    p.ta[1] = 100000;
    lf_reply_predict_outcome(&p, 1, 1);
    CHECK_EQ(p.ta[1], 100000 + CT / 8);
    /* a large estimate moves by 1/16 of itself */
    p.ta[1] = 3200000;
    lf_reply_predict_outcome(&p, 1, 0);
    CHECK_EQ(p.ta[1], 3000000);
    /* complete at no turnaround at all: the link may be faster than the
     * baud; observe again before predicting */
    p.ta[1] = 0;
    lf_reply_predict_outcome(&p, 1, 0);
    CHECK_EQ(lf_reply_predict_when(&p, 1, 0), 0);
    /* unknown slave: outcomes change nothing */
    lf_reply_predict_outcome(&p, 2, 1);
    CHECK_EQ(p.ta[2], -1);
}

static void test_every_64th_poll_observes(void)
{
    lf_reply_predict p;
    lf_reply_predict_init(&p, BAUD, 1);
    learn(&p, 3, 100000);
    int observed = 0;
    for (int i = 0; i < 3 * LF_REPLY_PREDICT_OBSERVE_EVERY; i++)
        observed += lf_reply_predict_when(&p, 3, 1000000) == 0;
    CHECK_EQ(observed, 3);
}

/* Complete reads in a row: from the third on, the down step doubles each
 * time (up to 8x), so an estimate learned late comes down in a few polls;
 * a read finding bytes missing resets it. Fails with a constant step. */
static void test_complete_reads_in_a_row_come_down_faster(void)
{
    lf_reply_predict p;
    lf_reply_predict_init(&p, BAUD, 1);
    learn(&p, 1, 1600000);
    lf_ns ta = 1600000;
    for (int i = 1; i <= 8; i++) {
        int k = i < 3 ? 0 : i - 2 < 3 ? i - 2 : 3;
        lf_ns step = ta / 16 > CT / 8 ? ta / 16 : CT / 8;
        ta = ta > step << k ? ta - (step << k) : 0;
        lf_reply_predict_outcome(&p, 1, 0);
        CHECK_EQ(p.ta[1], ta);
    }
    CHECK(p.ta[1] < 1600000 / 4);   /* a constant 1/16 step: 0.6x after 8 reads */
    lf_ns before = p.ta[1];
    lf_reply_predict_outcome(&p, 1, 1);                 /* resets the run */
    before += before / 16 > CT / 8 ? before / 16 : CT / 8;
    CHECK_EQ(p.ta[1], before);
    lf_reply_predict_outcome(&p, 1, 0);                 /* one step again */
    lf_ns step = before / 16 > CT / 8 ? before / 16 : CT / 8;
    CHECK_EQ(p.ta[1], before - step);
}

/* Observations spread wider than a character time keep a slave observed
 * (another run of LF_REPLY_PREDICT_TIGHT_N, until one is tight; the
 * estimate starts at its smallest); a predicted slave whose reads find more
 * than the last byte missing in 4 of its last 8 is observed again; reads
 * one byte short never count. Fails without the rules (one observation
 * starts the predictions, and they never stop). */
static void test_spread_turnaround_is_watched(void)
{
    lf_reply_predict p;
    lf_reply_predict_init(&p, BAUD, 1);
    /* 500..650 us, as 31 slaves served by one busy process answered */
    lf_ns spread[] = { 500000, 650000, 560000, 610000 };
    for (int run = 0; run < 3; run++)
        for (int i = 0; i < LF_REPLY_PREDICT_TIGHT_N; i++) {
            CHECK_EQ(lf_reply_predict_when(&p, 2, 0), 0);
            lf_reply_predict_observed(&p, 2, 0, spread[i] + WIRE);
        }
    /* a tight run (within a character time): predicted from its low end */
    lf_ns tight[] = { 540000, 540000 + CT, 560000, 550000 };
    for (int i = 0; i < LF_REPLY_PREDICT_TIGHT_N; i++) {
        CHECK_EQ(lf_reply_predict_when(&p, 2, 0), 0);
        lf_reply_predict_observed(&p, 2, 0, tight[i] + WIRE);
    }
    CHECK_EQ(lf_reply_predict_when(&p, 2, 0), 540000 + WIRE);
    for (int i = 0; i < 16; i++) {                      /* one byte short: fine */
        CHECK(lf_reply_predict_when(&p, 2, 0) != 0);
        lf_reply_predict_outcome(&p, 2, i % 2);
    }
    for (int i = 0; i < 3; i++) {                       /* three late of eight: fine */
        CHECK(lf_reply_predict_when(&p, 2, 0) != 0);
        lf_reply_predict_outcome(&p, 2, 3);
        lf_reply_predict_outcome(&p, 2, 0);
    }
    CHECK(lf_reply_predict_when(&p, 2, 0) != 0);
    lf_reply_predict_outcome(&p, 2, LF_FAP_OVERHEAD);   /* the fourth (nothing came) */
    for (int i = 0; i < LF_REPLY_PREDICT_TIGHT_N; i++) {
        CHECK_EQ(lf_reply_predict_when(&p, 2, 0), 0);
        lf_reply_predict_observed(&p, 2, 0, 600000 + WIRE);
    }
    CHECK_EQ(lf_reply_predict_when(&p, 2, 0), 600000 + WIRE);
    CHECK_EQ(lf_reply_predict_when(&p, 1, 0), 0);      /* other slaves untouched */
}

/* A slave that sent DATA in its turn is observed until a turn without:
 * its reply is a DATA frame and a DATA_DONE, whose end the estimate does
 * not know (predicting it cost 12-15 % of fap-data's exchanges/s). */
static void test_data_turn_is_observed(void)
{
    lf_reply_predict p;
    lf_reply_predict_init(&p, BAUD, 1);
    learn(&p, 4, 300000);
    CHECK_EQ(lf_reply_predict_when(&p, 4, 0), 300000 + WIRE);
    lf_reply_predict_turn(&p, 4, 1);
    CHECK_EQ(lf_reply_predict_when(&p, 4, 0), 0);
    CHECK_EQ(lf_reply_predict_when(&p, 4, 0), 0);
    lf_reply_predict_turn(&p, 4, 0);
    CHECK_EQ(lf_reply_predict_when(&p, 4, 0), 300000 + WIRE);
}

/* ---- a real master on the paced bus ---- */

/* The master engine thread's voluntary context switches (its wake-ups). */
static long thread_wakeups(const char *name)
{
    DIR *d = opendir("/proc/self/task");
    if (!d)
        return -1;
    long out = -1;
    struct dirent *de;
    while ((de = readdir(d)) && out < 0) {
        if (de->d_name[0] == '.')
            continue;
        char path[320], buf[4096];
        snprintf(path, sizeof path, "/proc/self/task/%s/comm", de->d_name);
        FILE *f = fopen(path, "r");
        if (!f)
            continue;
        int match = fgets(buf, sizeof buf, f) && strncmp(buf, name, strlen(name)) == 0;
        fclose(f);
        if (!match)
            continue;
        snprintf(path, sizeof path, "/proc/self/task/%s/status", de->d_name);
        if (!(f = fopen(path, "r")))
            continue;
        while (fgets(buf, sizeof buf, f))
            if (sscanf(buf, "voluntary_ctxt_switches: %ld", &out) == 1)
                break;
        fclose(f);
    }
    closedir(d);
    return out;
}

static uint64_t polls_of(fapx *h)
{
    fapx_stats st;
    fapx_get_stats(h, &st);
    return st.polls;
}

/* Wait until the master has made n more polls (10 s at most). */
static int wait_polls(fapx *h, uint64_t n)
{
    uint64_t end = polls_of(h) + n;
    for (int i = 0; i < 1000; i++) {
        if (polls_of(h) >= end)
            return 0;
        fapx_event ev;
        (void)fapx_event_wait(h, &ev, 10);   /* a timed wait: no busy loop */
    }
    return -ETIMEDOUT;
}

/* An idle poll cycle at 115200: SEND_DATA out, DATA_DONE in. Watching the
 * port, the master wakes for the reply's first piece, the hold's end and
 * the last byte (3.5-5 per cycle); reading at the predicted end, once,
 * plus one when the estimate was early (a third of the reads) and the
 * observations. */
static void test_idle_master_wakes_about_once_per_poll(void)
{
    fap_vbus *bus = open_bus(2, BAUD);
    REQUIRE(bus != NULL);
    fapx *m = NULL, *s = NULL;
    fapx_options o;
    fast_options(&o, FAPX_SLAVE, 1);
    o.port.baud = BAUD;
    REQUIRE(fapx_open(&s, fap_vbus_port_path(bus, 1), &o) == 0);
    fast_options(&o, FAPX_MASTER, 0);
    o.port.baud = BAUD;
    REQUIRE(fapx_open(&m, fap_vbus_port_path(bus, 0), &o) == 0);
    REQUIRE(pthread_setname_np(m->thread, "fap-test-master") == 0);
    CHECK_EQ(fapx_add_slave(m, 1), 0);
    CHECK_EQ(wait_event(m, FAPX_EV_SLAVE_ACTIVE, 1, 5000, NULL), 0);
    CHECK_EQ(wait_polls(m, 100), 0);          /* learn the turnaround */
    /* The best of up to ten windows: on a loaded machine a window where the
     * scheduler ran the master late drives it back to observing for a while
     * (correctly), which says nothing about the idle cost being asked about.
     * The bound sits halfway between the idle figure (~1.7) and what a
     * master that watches the port costs (4.5-5): CI beside other jobs saw
     * 3.2-3.7 in all of five windows once. */
    double per_poll = 1e9;
    for (int window = 0; window < 10 && per_poll >= 2.5; window++) {
        uint64_t p0 = polls_of(m);
        long w0 = thread_wakeups("fap-test-master");
        CHECK_EQ(wait_polls(m, 200), 0);
        long w1 = thread_wakeups("fap-test-master");
        uint64_t p1 = polls_of(m);
        REQUIRE(w0 >= 0 && w1 >= w0 && p1 > p0);
        double got = (double)(w1 - w0) / (double)(p1 - p0);
        fprintf(stderr, "master engine: %.2f wake-ups per poll cycle (%ld over %llu polls)\n",
                got, w1 - w0, (unsigned long long)(p1 - p0));
        if (got < per_poll)
            per_poll = got;
    }
    CHECK(per_poll < 3.5);    /* 4.5-5 when it watches the port */
    fapx_close(m);
    fapx_close(s);
    fap_vbus_close(bus);
}

UNIT_MAIN(UNIT(test_no_prediction_before_a_paced_reply), UNIT(test_learning_steps),
          UNIT(test_every_64th_poll_observes),
          UNIT(test_complete_reads_in_a_row_come_down_faster), UNIT(test_spread_turnaround_is_watched),
          UNIT(test_data_turn_is_observed),
          UNIT(test_idle_master_wakes_about_once_per_poll))
