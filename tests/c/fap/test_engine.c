/* Real engines (threads, timerfd, ptys) on the virtual bus, in one
 * process: a master and three slaves, a listed slave that never exists,
 * a slave that closes and comes back; data in every direction. */
#include "bus_util.h"
#include "fap/fapx_internal.h"
#include <sched.h>
#include <poll.h>
#include <pthread.h>
#include <time.h>
#include <unistd.h>

static fap_vbus *bus;
static fapx *master, *slave[4];

static void open_all(void)
{
    bus = open_bus(6, 0);
    fapx_options o;
    fast_options(&o, FAPX_MASTER, 0);
    CHECK_EQ(fapx_open(&master, fap_vbus_port_path(bus, 0), &o), 0);
    for (unsigned id = 1; id <= 3; id++) {
        fast_options(&o, FAPX_SLAVE, id);
        CHECK_EQ(fapx_open(&slave[id], fap_vbus_port_path(bus, id), &o), 0);
    }
}

static void close_all(void)
{
    ev_backlog_n = 0;
    for (unsigned id = 1; id <= 3; id++) {
        fapx_close(slave[id]);
        slave[id] = NULL;
    }
    fapx_close(master);
    master = NULL;
    fap_vbus_close(bus);
    bus = NULL;
}

static void test_open_errors(void)
{
    fapx_options o;
    fapx *h = NULL;
    fast_options(&o, FAPX_SLAVE, 0);
    CHECK_EQ(fapx_open(&h, "/dev/null", &o), -EINVAL);
    fast_options(&o, FAPX_SLAVE, 32);
    CHECK_EQ(fapx_open(&h, "/dev/null", &o), -EINVAL);
    fast_options(&o, FAPX_MASTER, 3);
    CHECK_EQ(fapx_open(&h, "/dev/null", &o), -EINVAL);
    fast_options(&o, 7, 0);
    CHECK_EQ(fapx_open(&h, "/dev/null", &o), -EINVAL);
    fast_options(&o, FAPX_MASTER, 0);
    CHECK(fapx_open(&h, "/nonexistent/ttyFAP", &o) < 0);
    CHECK(h == NULL);
}

static void test_master_and_slaves_exchange(void)
{
    open_all();
    REQUIRE(bus && master && slave[1] && slave[2] && slave[3]);
    CHECK_EQ(fapx_add_slave(slave[1], 2), -EPERM);
    for (unsigned id = 1; id <= 4; id++)
        CHECK_EQ(fapx_add_slave(master, id), 0);
    CHECK_EQ(fapx_add_slave(master, 4), -EEXIST);
    CHECK_EQ(fapx_add_slave(master, 0), -EINVAL);
    CHECK_EQ(fapx_add_slave(master, 32), -EINVAL);
    for (unsigned id = 1; id <= 3; id++)
        CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, id, 2000, NULL), 0);
    CHECK_EQ(wait_event(master, FAPX_EV_ID_TIMEOUT, 4, 2000, NULL), 0);
    CHECK_EQ(fapx_slave_active(master, 1), 1);
    CHECK_EQ(fapx_slave_active(master, 4), 0);
    CHECK_EQ(fapx_slave_active(master, 5), -ENOENT);
    CHECK_EQ(fapx_active_mask(master), 0xEu);
    CHECK_EQ(fapx_listed_mask(master), 0x1Eu);

    /* tx validation */
    uint8_t big[1025] = { 0 };
    CHECK_EQ(fapx_tx(master, 0, "x", 1), -EINVAL);      /* master to itself */
    CHECK_EQ(fapx_tx(master, 32, "x", 1), -EINVAL);
    CHECK_EQ(fapx_tx(master, 1, big, 0), -EINVAL);
    CHECK_EQ(fapx_tx(master, 1, big, 1025), -EINVAL);
    CHECK_EQ(fapx_tx(slave[2], 2, "x", 1), -EINVAL);    /* slave to itself */

    /* 20 rounds: master -> each slave, each slave -> master and -> next slave */
    char msg[64];
    for (int r = 0; r < 20; r++) {
        for (unsigned id = 1; id <= 3; id++) {
            int n = snprintf(msg, sizeof msg, "m>%u#%d", id, r);
            CHECK_EQ(fapx_tx(master, id, msg, (size_t)n), 0);
            n = snprintf(msg, sizeof msg, "%u>m#%d", id, r);
            CHECK_EQ(fapx_tx(slave[id], 0, msg, (size_t)n), 0);
            n = snprintf(msg, sizeof msg, "%u>%u#%d", id, id % 3 + 1, r);
            CHECK_EQ(fapx_tx(slave[id], id % 3 + 1, msg, (size_t)n), 0);
        }
    }
    /* receive in order, from the right source, nothing twice */
    int bad = 0;
    uint8_t buf[FAPX_MAX_DATA];
    unsigned src;
    int next_from[4] = { 0 };
    for (int k = 0; k < 60; k++) {
        int n = fapx_rx_wait(master, buf, sizeof buf, &src, 2000);
        REQUIRE(n > 0);
        buf[n] = 0;
        int r = -1;
        unsigned from = 0;
        if (sscanf((char *)buf, "%u>m#%d", &from, &r) != 2 || from != src || r != next_from[src]++)
            bad++;
    }
    CHECK_EQ(bad, 0);
    for (unsigned id = 1; id <= 3; id++) {
        int m_next = 0, s_next = 0;
        for (int k = 0; k < 40; k++) {
            int n = fapx_rx_wait(slave[id], buf, sizeof buf, &src, 2000);
            REQUIRE(n > 0);
            buf[n] = 0;
            unsigned a = 99, b = 99;
            int r = -1;
            if (src == 0) {
                if (sscanf((char *)buf, "m>%u#%d", &a, &r) != 2 || a != id || r != m_next++)
                    bad++;
            } else if (sscanf((char *)buf, "%u>%u#%d", &a, &b, &r) != 3 || a != src ||
                       b != id || src != (id + 1) % 3 + 1 || r != s_next++) {
                bad++;
            }
        }
        CHECK_EQ(fapx_rx(slave[id], buf, sizeof buf, &src), -EAGAIN);
    }
    CHECK_EQ(bad, 0);
    CHECK_EQ(fapx_rx(master, buf, sizeof buf, &src), -EAGAIN);

    /* one more message from slave 3 comes in a later data cycle */
    CHECK_EQ(fapx_tx(slave[3], 0, "sync", 4), 0);
    CHECK_EQ(fapx_rx_wait(master, buf, sizeof buf, &src, 2000), 4);
    fapx_stats st;
    fapx_get_stats(master, &st);
    CHECK(st.cycles > 0);
    CHECK(st.polls > 0);
    CHECK_EQ(st.data_tx, 60);
    CHECK_EQ(st.data_rx, 61);
    CHECK_EQ(st.crc_errors, 0);
    CHECK(st.frames_tx > 0 && st.bytes_tx > st.frames_tx * 15 - 1);
    CHECK(st.id_timeouts >= 1);
    close_all();
}

static void test_slave_dies_and_comes_back(void)
{
    open_all();
    REQUIRE(bus && master);
    for (unsigned id = 1; id <= 3; id++)
        fapx_add_slave(master, id);
    for (unsigned id = 1; id <= 3; id++)
        CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, id, 2000, NULL), 0);
    backlog_forget(slave[2]);
    fapx_close(slave[2]);
    slave[2] = NULL;
    fapx_event ev;
    CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_INACTIVE, 2, 2000, &ev), 0);
    CHECK_EQ(fapx_slave_active(master, 2), 0);
    fapx_stats st;
    fapx_get_stats(master, &st);
    CHECK(st.data_done_timeouts >= 1);
    /* the others are still polled */
    uint64_t polls = st.polls;
    CHECK_EQ(fapx_tx(slave[1], 0, "still here", 10), 0);
    uint8_t buf[FAPX_MAX_DATA];
    unsigned src;
    CHECK_EQ(fapx_rx_wait(master, buf, sizeof buf, &src, 2000), 10);
    CHECK_EQ(src, 1);
    /* a second message comes in a later turn: the first turn's DATA_DONE has counted */
    CHECK_EQ(fapx_tx(slave[1], 0, "again", 5), 0);
    CHECK_EQ(fapx_rx_wait(master, buf, sizeof buf, &src, 2000), 5);
    fapx_get_stats(master, &st);
    CHECK(st.polls > polls);
    /* back on the same port: active again at the next ID cycle */
    fapx_options o;
    fast_options(&o, FAPX_SLAVE, 2);
    CHECK_EQ(fapx_open(&slave[2], fap_vbus_port_path(bus, 2), &o), 0);
    int64_t t0 = fap_port_now_ns();
    CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, 2, 2000, NULL), 0);
    CHECK(fap_port_now_ns() - t0 < 2000000000LL);
    CHECK_EQ(fapx_tx(slave[2], 1, "back", 4), 0);
    CHECK_EQ(fapx_rx_wait(slave[1], buf, sizeof buf, &src, 2000), 4);
    CHECK_EQ(src, 2);
    /* removed while running: never polled again */
    CHECK_EQ(fapx_remove_slave(master, 3), 0);
    CHECK_EQ(fapx_remove_slave(master, 3), -ENOENT);
    CHECK_EQ(fapx_slave_active(master, 3), -ENOENT);
    close_all();
}

static pthread_mutex_t cb_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t cb_cond = PTHREAD_COND_INITIALIZER;
static int cb_rx;
static unsigned cb_src = 99;

/* Called from the engine thread. */
static void on_cb(void *ctx, const fapx_event *ev)
{
    (void)ctx;
    if (ev->type != FAPX_EV_RX)
        return;
    pthread_mutex_lock(&cb_lock);
    cb_rx++;
    cb_src = ev->id;
    pthread_cond_broadcast(&cb_cond);
    pthread_mutex_unlock(&cb_lock);
}

static void test_notify_fd_and_callback(void)
{
    open_all();
    REQUIRE(bus && master);
    int fd = fapx_notify_fd(slave[1]);
    CHECK(fd >= 0);
    struct pollfd pf = { .fd = fd, .events = POLLIN };
    CHECK_EQ(poll(&pf, 1, 0), 0);
    fapx_set_callback(slave[1], on_cb, NULL);
    fapx_add_slave(master, 1);
    CHECK_EQ(fapx_tx(master, 1, "ping", 4), 0);
    CHECK_EQ(fapx_tx(master, 1, "pong", 4), 0);
    CHECK_EQ(poll(&pf, 1, 2000), 1);
    /* level-triggered: stays readable until both queues are empty */
    uint8_t buf[16];
    unsigned src;
    fapx_event ev;
    pthread_mutex_lock(&cb_lock);
    struct timespec dl;
    clock_gettime(CLOCK_REALTIME, &dl);
    dl.tv_sec += 2;
    while (cb_rx < 2 && pthread_cond_timedwait(&cb_cond, &cb_lock, &dl) == 0)
        ;
    CHECK_EQ(cb_rx, 2);
    CHECK_EQ(cb_src, 0);
    pthread_mutex_unlock(&cb_lock);
    CHECK_EQ(fapx_rx_pending(slave[1]), 2);
    CHECK_EQ(poll(&pf, 1, 0), 1);
    CHECK_EQ(fapx_rx(slave[1], buf, 2, &src), -EMSGSIZE);     /* kept queued */
    CHECK_EQ(fapx_rx(slave[1], buf, sizeof buf, &src), 4);
    CHECK_EQ(poll(&pf, 1, 0), 1);
    CHECK_EQ(fapx_rx(slave[1], buf, sizeof buf, &src), 4);
    while (fapx_event_get(slave[1], &ev) == 0)
        ;
    CHECK_EQ(poll(&pf, 1, 0), 0);
    CHECK_EQ(fapx_rx_wait(slave[1], buf, sizeof buf, &src, 10), -ETIMEDOUT);
    close_all();
}


/* A corrupted DATA_DONE: the master counts the bad frame, marks the slave
 * inactive at the DATA_DONE timeout and takes it back at the ID cycle. */
static void test_corrupted_frame_and_recovery(void)
{
    open_all();
    REQUIRE(bus && master);
    fapx_add_slave(master, 1);
    CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, 1, 2000, NULL), 0);
    CHECK_EQ(fap_vbus_corrupt_next(bus, 1, 15), 0);
    fapx_event ev;
    CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_INACTIVE, 1, 2000, &ev), 0);
    CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, 1, 2000, NULL), 0);
    fapx_stats st;
    fapx_get_stats(master, &st);
    CHECK(st.crc_errors + st.framing_errors + st.garbage_bytes + st.gap_timeouts > 0);
    CHECK(st.data_done_timeouts >= 1);
    close_all();
}

/* Random bit errors on every port: frames get lost (FAP does not
 * retransmit) but nothing corrupted or duplicated is ever delivered. */
static void test_bit_errors_never_deliver_garbage(void)
{
    open_all();
    REQUIRE(bus && master);
    for (unsigned id = 1; id <= 3; id++)
        fapx_add_slave(master, id);
    for (unsigned id = 1; id <= 3; id++)
        CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, id, 2000, NULL), 0);
    CHECK_EQ(fap_vbus_set_fault(bus, -1, 0.002, 0.0), 0);
    char msg[200];
    static uint8_t seen[4][200];
    memset(seen, 0, sizeof seen);
    for (int k = 0; k < 150; k++) {
        unsigned id = 1 + (unsigned)k % 3;
        int n = snprintf(msg, sizeof msg, "m>%u#%03d:%0120d", id, k, k);
        fapx_tx_wait(master, id, msg, (size_t)n, 2000);
    }
    fapx_flush(master, 5000);
    int bad = 0, got = 0;
    for (unsigned id = 1; id <= 3; id++) {
        uint8_t buf[FAPX_MAX_DATA + 1];
        unsigned src;
        int n;
        while ((n = fapx_rx_wait(slave[id], buf, sizeof buf - 1, &src, 50)) > 0) {
            buf[n] = 0;
            unsigned to = 0;
            int k = -1, k2 = -2;
            char expect[200];
            if (sscanf((char *)buf, "m>%u#%d:%d", &to, &k, &k2) != 3 || to != id || src != 0 ||
                k != k2 || k < 0 || k >= 150 || seen[id][k]++) {
                bad++;
                continue;
            }
            snprintf(expect, sizeof expect, "m>%u#%03d:%0120d", id, k, k);
            if (strcmp((char *)buf, expect) != 0)
                bad++;
            got++;
        }
    }
    fap_vbus_set_fault(bus, -1, 0.0, 0.0);
    fapx_stats st;
    fapx_get_stats(slave[1], &st);
    fprintf(stderr, "bit errors: %d of 150 delivered intact, %d bad; slave 1 crc %llu framing %llu\n",
            got, bad, (unsigned long long)st.crc_errors, (unsigned long long)st.framing_errors);
    CHECK_EQ(bad, 0);
    CHECK(got > 0);
    close_all();
}

/* The slave's port disconnects: its handle reports the loss and the
 * reopen, and the master takes it back. */
static void test_port_lost_and_reopened(void)
{
    open_all();
    REQUIRE(bus && master);
    fapx_add_slave(master, 1);
    CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, 1, 2000, NULL), 0);
    CHECK_EQ(fap_vbus_disconnect(bus, 1, 50), 0);
    CHECK_EQ(wait_event(slave[1], FAPX_EV_PORT_LOST, 1, 2000, NULL), 0);
    CHECK_EQ(wait_event(slave[1], FAPX_EV_PORT_REOPENED, 1, 3000, NULL), 0);
    CHECK_EQ(fapx_tx(slave[1], 0, "back", 4), 0);
    uint8_t buf[16];
    unsigned src;
    CHECK_EQ(fapx_rx_wait(master, buf, sizeof buf, &src, 3000), 4);
    CHECK_EQ(src, 1);
    fapx_stats st;
    fapx_get_stats(slave[1], &st);
    CHECK_EQ(st.port_lost, 1);
    CHECK(st.port_reopened >= 1);
    close_all();
}

/* A master whose only slave never answers sleeps between ID cycles: one
 * QUERY_ID per idc, nothing else on the wire (no busy loop). */
static void test_idle_master_queries_once_per_idc(void)
{
    bus = open_bus(2, 0);
    REQUIRE(bus);
    fapx_options o;
    fast_options(&o, FAPX_MASTER, 0);
    int rc = fapx_open(&master, fap_vbus_port_path(bus, 0), &o);
    REQUIRE(rc == 0);
    CHECK_EQ(fapx_add_slave(master, 9), 0);
    fapx_event a = { 0 }, b = { 0 }, c = { 0 };
    CHECK_EQ(wait_event(master, FAPX_EV_ID_TIMEOUT, 9, 3000, &a), 0);
    CHECK_EQ(wait_event(master, FAPX_EV_ID_TIMEOUT, 9, 3000, &b), 0);
    CHECK_EQ(wait_event(master, FAPX_EV_ID_TIMEOUT, 9, 3000, &c), 0);
    /* QUERY_ID every idc: ID cycles start exactly idc apart; the timeouts
     * follow each query's transmission, whose duration varies a little */
    int64_t slack = 20000000;
    fprintf(stderr, "idc gaps: %lld %lld ms\n", (long long)(b.time_ns - a.time_ns) / 1000000, (long long)(c.time_ns - b.time_ns) / 1000000);
    CHECK(b.time_ns - a.time_ns >= (int64_t)o.idc_us * 1000 - slack);
    CHECK(c.time_ns - b.time_ns >= (int64_t)o.idc_us * 1000 - slack);
    CHECK(c.time_ns - b.time_ns < 3 * (int64_t)o.idc_us * 1000);
    fapx_stats st;
    fapx_get_stats(master, &st);
    CHECK(st.frames_tx >= 3 && st.frames_tx <= 4);
    CHECK_EQ(st.cycles, 0);
    fapx_close(master);
    master = NULL;
    ev_backlog_n = 0;
    fap_vbus_close(bus);
    bus = NULL;
}

/* A small receive queue: frames beyond it are dropped, counted and
 * reported (FAPX_EV_RX_OVERFLOW); the ones kept are intact and in order. */
static void test_rx_queue_overflow(void)
{
    bus = open_bus(2, 0);
    REQUIRE(bus);
    fapx_options o;
    fast_options(&o, FAPX_MASTER, 0);
    int rc = fapx_open(&master, fap_vbus_port_path(bus, 0), &o);
    REQUIRE(rc == 0);
    fast_options(&o, FAPX_SLAVE, 1);
    o.rx_depth = 4;
    rc = fapx_open(&slave[1], fap_vbus_port_path(bus, 1), &o);
    REQUIRE(rc == 0);
    for (int k = 0; k < 10; k++) {
        char m[8];
        int n = snprintf(m, sizeof m, "#%d", k);
        CHECK_EQ(fapx_tx(master, 1, m, (size_t)n), 0);
    }
    CHECK_EQ(fapx_flush(master, 2000), 0);
    for (int k = 4; k < 10; k++)
        CHECK_EQ(wait_event(slave[1], FAPX_EV_RX_OVERFLOW, 0, 2000, NULL), 0);
    fapx_stats st;
    fapx_get_stats(slave[1], &st);
    CHECK_EQ(st.rx_dropped, 6);
    CHECK_EQ(fapx_rx_pending(slave[1]), 4);
    for (int k = 0; k < 4; k++) {
        char buf[16];
        unsigned src;
        int n = fapx_rx(slave[1], buf, sizeof buf, &src);
        CHECK_EQ(n, 2);
        CHECK_EQ(buf[1], '0' + k);
    }
    close_all();
}

/* A 2-wire bus where every node hears its own bytes: with the port's echo
 * suppression the echo is removed; without it the engine ignores frames
 * with its own source ID. Data flows either way. */
static void test_echo_bus(void)
{
    for (int suppress = 1; suppress >= 0; suppress--) {
        fap_vbus_options bo;
        fap_vbus_options_init(&bo);
        bo.n_ports = 2;
        bo.echo = 1;
        int rc = fap_vbus_open(&bus, &bo);
        REQUIRE(rc == 0);
        fapx_options o;
        fast_options(&o, FAPX_MASTER, 0);
        o.port.echo_suppression = suppress;
        rc = fapx_open(&master, fap_vbus_port_path(bus, 0), &o);
        REQUIRE(rc == 0);
        fast_options(&o, FAPX_SLAVE, 1);
        o.port.echo_suppression = suppress;
        rc = fapx_open(&slave[1], fap_vbus_port_path(bus, 1), &o);
        REQUIRE(rc == 0);
        fapx_add_slave(master, 1);
        CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, 1, 2000, NULL), 0);
        CHECK_EQ(fapx_tx(slave[1], 0, "up", 2), 0);
        CHECK_EQ(fapx_tx(master, 1, "down", 4), 0);
        char buf[16];
        unsigned src = 99;
        CHECK_EQ(fapx_rx_wait(master, buf, sizeof buf, &src, 2000), 2);
        CHECK_EQ(src, 1);
        CHECK_EQ(fapx_rx_wait(slave[1], buf, sizeof buf, &src, 2000), 4);
        CHECK_EQ(src, 0);
        fapx_stats st;
        fapx_get_stats(master, &st);
        CHECK_EQ(st.collisions, 0);
        CHECK_EQ(st.crc_errors, 0);
        if (suppress)
            CHECK_EQ(st.unexpected, 0);      /* no echo reached the engine */
        else
            CHECK(st.unexpected > 0);        /* its own frames, ignored */
        close_all();
    }
}

/* fapx_close wakes a thread blocked in fapx_rx_wait: it returns -ESHUTDOWN
 * and close waits for it to leave before freeing the handle. */
static fapx *blocked_h;
static int blocked_rc = 1;
static void *blocked_reader(void *arg)
{
    (void)arg;
    char buf[16];
    blocked_rc = fapx_rx_wait(blocked_h, buf, sizeof buf, NULL, -1);
    return NULL;
}

static void test_close_wakes_blocked_reader(void)
{
    bus = open_bus(2, 0);
    REQUIRE(bus);
    fapx_options o;
    fast_options(&o, FAPX_SLAVE, 3);
    int rc = fapx_open(&blocked_h, fap_vbus_port_path(bus, 1), &o);
    REQUIRE(rc == 0);
    pthread_t th;
    pthread_create(&th, NULL, blocked_reader, NULL);
    /* wait until the reader is inside fapx_rx_wait (white box: the
     * handle's waiter count, read under its lock) */
    for (;;) {
        pthread_mutex_lock(&blocked_h->lock);
        unsigned w = blocked_h->waiters;
        pthread_mutex_unlock(&blocked_h->lock);
        if (w)
            break;
        sched_yield();
    }
    fapx_close(blocked_h);
    pthread_join(th, NULL);
    CHECK_EQ(blocked_rc, -ESHUTDOWN);
    fap_vbus_close(bus);
    bus = NULL;
}

UNIT_MAIN(UNIT(test_open_errors), UNIT(test_master_and_slaves_exchange),
          UNIT(test_slave_dies_and_comes_back), UNIT(test_notify_fd_and_callback),
          UNIT(test_corrupted_frame_and_recovery), UNIT(test_bit_errors_never_deliver_garbage),
          UNIT(test_port_lost_and_reopened),
          UNIT(test_idle_master_queries_once_per_idc),
          UNIT(test_rx_queue_overflow), UNIT(test_echo_bus), UNIT(test_close_wakes_blocked_reader))
