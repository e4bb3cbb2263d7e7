/* Issue 12 defects 3 and 7 on real engines (virtual bus, threads):
 * every loss shows in a counter, huge timing values are no UB.
 * Ports: 0 master, 1 slave 1. */
#include <limits.h>
#include <pthread.h>
#include <semaphore.h>
#include <time.h>
#include <unistd.h>

#include "../fap/bus_util.h"

static sem_t ev_sem;
static unsigned ev_seen;    /* atomic: events the callback saw */

static void count_cb(void *ctx, const fapx_event *ev)
{
    (void)ctx;
    if (ev->type == FAPX_EV_ID_TIMEOUT) {
        __atomic_fetch_add(&ev_seen, 1, __ATOMIC_ACQ_REL);
        sem_post(&ev_sem);
    }
}

static int sem_wait_ms(sem_t *s, int ms)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    ts.tv_sec += ms / 1000;
    ts.tv_nsec += (long)(ms % 1000) * 1000000L;
    if (ts.tv_nsec >= 1000000000L) {
        ts.tv_sec++;
        ts.tv_nsec -= 1000000000L;
    }
    return sem_timedwait(s, &ts);
}


/* A full event queue used to drop events without a trace. */
static void test_full_event_queue_counted(void)
{
    fap_vbus *b = open_bus(2, 0);
    REQUIRE(b);
    fapx_options o;
    fast_options(&o, FAPX_MASTER, 0);
    o.id_answer_us = 2000;
    o.ev_depth = 2;
    fapx *m = NULL;
    REQUIRE(fapx_open(&m, fap_vbus_port_path(b, 0), &o) == 0);
    sem_init(&ev_sem, 0, 0);
    fapx_set_callback(m, count_cb, NULL);
    for (unsigned id = 1; id <= 6; id++)     /* nobody there: 6 ID timeouts */
        CHECK_EQ(fapx_add_slave(m, id), 0);
    for (int i = 0; i < 6; i++)
        REQUIRE(sem_wait_ms(&ev_sem, 10000) == 0);
    fapx_set_callback(m, NULL, NULL);
    fapx_stats st;
    fapx_get_stats(m, &st);
    unsigned queued = 0;
    fapx_event ev;
    while (fapx_event_get(m, &ev) == 0)
        queued++;
    CHECK_EQ(queued, 2);
    CHECK(st.ev_dropped >= 4);          /* every event beyond the 2 kept */
    CHECK(st.ev_dropped + 2 >= st.id_timeouts);
    fapx_close(m);
    fap_vbus_close(b);
    sem_destroy(&ev_sem);
}

/* FAP has no acknowledgement: DATA to a slave that then misses DATA_DONE,
 * or that is not active when it is sent, is counted at the sender. */
static void test_data_to_dead_slave_counted(void)
{
    fap_vbus *b = open_bus(2, 0);
    REQUIRE(b);
    fapx_options o;
    fast_options(&o, FAPX_MASTER, 0);
    o.idc_us = 60000000;                 /* no ID cycle during the test */
    fapx *m = NULL, *s = NULL;
    REQUIRE(fapx_open(&m, fap_vbus_port_path(b, 0), &o) == 0);
    fast_options(&o, FAPX_SLAVE, 1);
    REQUIRE(fapx_open(&s, fap_vbus_port_path(b, 1), &o) == 0);
    REQUIRE(fapx_add_slave(m, 1) == 0);
    REQUIRE(wait_event(m, FAPX_EV_SLAVE_ACTIVE, 1, 10000, NULL) == 0);
    /* one message that gets through: the counters stay at 0 */
    uint8_t msg[16] = "alive";
    REQUIRE(fapx_tx(m, 1, msg, 5) == 0);
    uint8_t buf[64];
    CHECK_EQ(fapx_rx_wait(s, buf, sizeof buf, NULL, 10000), 5);
    /* and the poll after it completed (its DATA_DONE confirms it) */
    fapx_stats st;
    fapx_get_stats(m, &st);
    uint64_t polls0 = st.polls;
    for (int i = 0; i < 1000 && st.polls < polls0 + 2; i++) {
        usleep(2000);
        fapx_get_stats(m, &st);
    }
    REQUIRE(st.polls >= polls0 + 2);
    CHECK_EQ(st.tx_unconfirmed + st.tx_to_inactive, 0);
    /* the slave falls off the bus: it hears nothing, says nothing. The 3
     * frames go out before or after the master notices (its DATA_DONE
     * timeout): either way each is counted once. */
    REQUIRE(fap_vbus_silence(b, 1, 60000) == 0);
    for (int i = 0; i < 3; i++)
        REQUIRE(fapx_tx(m, 1, msg, 8) == 0);
    REQUIRE(wait_event(m, FAPX_EV_SLAVE_INACTIVE, 1, 10000, NULL) == 0);
    CHECK_EQ(fapx_flush(m, 10000), 0);
    fapx_get_stats(m, &st);
    CHECK_EQ(st.tx_unconfirmed + st.tx_to_inactive, 3);
    uint64_t inactive0 = st.tx_to_inactive;
    /* now inactive: anything sent to it is counted at once */
    for (int i = 0; i < 2; i++)
        REQUIRE(fapx_tx(m, 1, msg, 8) == 0);
    CHECK_EQ(fapx_flush(m, 10000), 0);
    fapx_get_stats(m, &st);
    CHECK_EQ(st.tx_to_inactive, inactive0 + 2);
    CHECK_EQ(st.data_tx, 6);
    fapx_stats ss;
    fapx_get_stats(s, &ss);
    /* every DATA the master sent is delivered or in a loss counter */
    CHECK_EQ(ss.data_rx + st.tx_unconfirmed + st.tx_to_inactive, st.data_tx);
    fapx_close(s);
    fapx_close(m);
    fap_vbus_close(b);
}

/* Timing values near UINT64_MAX used to overflow a signed multiply. */
static void test_huge_timing_no_ub(void)
{
    fap_vbus *b = open_bus(2, 0);
    REQUIRE(b);
    fapx_options o;
    fast_options(&o, FAPX_MASTER, 0);
    o.idc_us = o.id_answer_us = o.data_done_us = o.send_budget_us = UINT64_MAX;
    o.gap_us = o.reopen_us = UINT64_MAX;
    fapx *m = NULL;
    REQUIRE(fapx_open(&m, fap_vbus_port_path(b, 0), &o) == 0);
    CHECK_EQ(fapx_add_slave(m, 3), 0);
    uint8_t d[4] = {1, 2, 3, 4};
    CHECK_EQ(fapx_tx(m, 3, d, 4), 0);
    CHECK_EQ(fapx_flush(m, 20), -ETIMEDOUT);      /* waiting ~3 years for slave 3's ID */
    fapx_event ev;
    CHECK_EQ(fapx_event_wait(m, &ev, 20), -ETIMEDOUT);   /* the ID answer never times out */
    fapx_close(m);
    o.idc_us = o.id_answer_us = o.data_done_us = o.send_budget_us = 9300000000000000ull;
    o.gap_us = o.reopen_us = 9300000000000000ull;        /* just above INT64_MAX ns */
    REQUIRE(fapx_open(&m, fap_vbus_port_path(b, 0), &o) == 0);
    CHECK_EQ(fapx_add_slave(m, 3), 0);
    fapx_close(m);
    fap_vbus_close(b);
}

static void test_strerror_extremes(void)
{
    const int codes[] = {INT_MIN, INT_MIN + 1, -1, 0, 1, -4096, 4096, INT_MAX};
    for (size_t i = 0; i < sizeof codes / sizeof codes[0]; i++) {
        CHECK(fapx_strerror(codes[i]) != NULL);
        CHECK(fap_port_strerror(codes[i]) != NULL);
    }
    CHECK(strcmp(fapx_strerror(INT_MIN), "unknown error") == 0);
}

UNIT_MAIN(UNIT(test_strerror_extremes), UNIT(test_huge_timing_no_ub),
          UNIT(test_full_event_queue_counted), UNIT(test_data_to_dead_slave_counted))
