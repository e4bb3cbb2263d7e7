/* Issue 26 item 2 and 4: a close never waits out the line or a timeout.
 * A FAP handle on a pty nobody reads (or a reader at 200 B/s) used to take
 * ~20 s in fapx_close (each queued 1 kB frame waited its write timeout);
 * an exec master's transaction waited its whole reply timeout. */
#include <fcntl.h>
#include <pthread.h>
#include <stdlib.h>
#include <sys/eventfd.h>
#include <time.h>
#include <unistd.h>

#include "exec_async_engine.h"
#include "../fap/bus_util.h"

#define CLOSE_BOUND_NS 500000000LL   /* the documented bound: 0.5 s */

/* A pty pair; *peer is the side this test reads (or leaves unread). */
static int open_pty(int *peer, char *name, size_t cap)
{
    int m = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (m < 0 || grantpt(m) || unlockpt(m) || ptsname_r(m, name, cap)) {
        if (m >= 0)
            close(m);
        return -1;
    }
    *peer = m;
    return 0;
}

static void sleep_ms(int ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

struct flusher { fapx *h; int rc; };
static void *flush_forever(void *arg)
{
    struct flusher *f = arg;
    f->rc = fapx_flush(f->h, -1);
    return NULL;
}

struct slow_reader { int fd; int stop; };
/* The far end at ~200 B/s: 20 bytes every 100 ms (load, not synchronisation). */
static void *read_slowly(void *arg)
{
    struct slow_reader *r = arg;
    char buf[20];
    while (!__atomic_load_n(&r->stop, __ATOMIC_ACQUIRE)) {
        if (read(r->fd, buf, sizeof buf) < 0) { /* EAGAIN: nothing yet */ }
        sleep_ms(100);
    }
    return NULL;
}

/* Queue 40 frames of 1000 bytes for a listed slave, wait until the data
 * turn has begun, close with a flush() waiting: bounded, the waiter gets
 * -ESHUTDOWN, the frames the line did not take are counted. */
static void close_with_undrained_output(int slow)
{
    int peer;
    char name[128];
    REQUIRE(open_pty(&peer, name, sizeof name) == 0);
    fcntl(peer, F_SETFL, O_NONBLOCK);
    struct slow_reader rd = {peer, 0};
    pthread_t rt;
    if (slow)
        REQUIRE(pthread_create(&rt, NULL, read_slowly, &rd) == 0);
    fapx_options o;
    fast_options(&o, FAPX_MASTER, 0);
    o.tx_depth = 64;
    fapx *h = NULL;
    REQUIRE(fapx_open(&h, name, &o) == 0);
    CHECK_EQ(fapx_add_slave(h, 5), 0);
    static uint8_t data[1000];
    for (int i = 0; i < 40; i++)
        CHECK_EQ(fapx_tx(h, 5, data, sizeof data), 0);
    fapx_stats st;
    int64_t end = fap_port_now_ns() + 10LL * 1000000000LL;
    do {                               /* the data turn has begun */
        sleep_ms(5);
        fapx_get_stats(h, &st);
    } while (st.data_tx < 2 && fap_port_now_ns() < end);
    CHECK(st.data_tx >= 2);
    struct flusher f = {h, 1};
    pthread_t ft;
    REQUIRE(pthread_create(&ft, NULL, flush_forever, &f) == 0);
    int64_t t0 = fap_port_now_ns();
    fapx_stats fin;
    fapx_close_stats(h, &fin);
    int64_t took = fap_port_now_ns() - t0;
    pthread_join(ft, NULL);
    fprintf(stderr, "  %s reader: close %.3f s, %llu frames sent, %llu abandoned\n",
            slow ? "200 B/s" : "no", (double)took / 1e9, (unsigned long long)fin.data_tx,
            (unsigned long long)fin.tx_abandoned);
    CHECK(took < CLOSE_BOUND_NS);
    CHECK_EQ(f.rc, -ESHUTDOWN);
    CHECK(fin.tx_abandoned >= 1);
    CHECK(fin.data_tx + fin.tx_abandoned >= 40);   /* every frame sent or counted */
    fapx_close_stats(NULL, &fin);                  /* NULL handle: nothing to do */
    fapx_close_stats(NULL, NULL);
    if (slow) {
        __atomic_store_n(&rd.stop, 1, __ATOMIC_RELEASE);
        pthread_join(rt, NULL);
    }
    close(peer);
}

static void test_fapx_close_nobody_reading(void) { close_with_undrained_output(0); }
static void test_fapx_close_reader_200_bps(void) { close_with_undrained_output(1); }

struct transactor { execMaster *m; int rc; };
static void *transact(void *arg)
{
    struct transactor *t = arg;
    byte reply[8];
    word len = 0;
    t->rc = execMasterTransact(t->m, 3, (const byte *)"x", 1, reply, sizeof reply, &len);
    return NULL;
}

/* An exec master waiting 10 s for a node that never answers: execMasterStop
 * from another thread ends it at once with -ECANCELED. */
static void test_exec_master_stop_ends_transaction(void)
{
    int peer;
    char name[128];
    REQUIRE(open_pty(&peer, name, sizeof name) == 0);
    fap_port_options po;
    fap_port_options_init(&po);
    po.rs485_mode = FAP_RS485_NONE;
    execMasterOptions mo;
    execMasterOptionsInit(&mo);
    mo.reply_timeout_us = 10000000;
    mo.retries = 0;
    execMaster *m = NULL;
    REQUIRE(execMasterOpen(&m, name, &po, &mo) == 0);
    struct transactor t = {m, 1};
    pthread_t th;
    REQUIRE(pthread_create(&th, NULL, transact, &t) == 0);
    execMasterStats st;
    int64_t end = fap_port_now_ns() + 10LL * 1000000000LL;
    do {
        sleep_ms(5);
        execMasterGetStats(m, &st);
    } while (st.tx_frames < 1 && fap_port_now_ns() < end);
    CHECK_EQ(st.tx_frames, 1);
    int64_t t0 = fap_port_now_ns();
    execMasterStop(m);
    pthread_join(th, NULL);
    int64_t took = fap_port_now_ns() - t0;
    fprintf(stderr, "  exec transaction ended %.3f s after the stop\n", (double)took / 1e9);
    CHECK(took < CLOSE_BOUND_NS);
    CHECK_EQ(t.rc, -ECANCELED);
    byte r[4];
    word n;
    CHECK_EQ(execMasterTransact(m, 3, (const byte *)"x", 1, r, sizeof r, &n), -ECANCELED);
    CHECK_EQ(execMasterBroadcast(m, (const byte *)"x", 1), -ECANCELED);
    execMasterStop(NULL);
    execMasterClose(m);
    close(peer);
}

/* The public form of the cancellable port: NULL cancel fd refused; a write
 * that waits for room on a pty nobody reads ends once the fd is readable. */
static void test_port_cancellable_write(void)
{
    int peer;
    char name[128];
    REQUIRE(open_pty(&peer, name, sizeof name) == 0);
    fap_port *p = NULL;
    CHECK_EQ(fap_port_open_cancellable(&p, name, NULL, NULL), -EINVAL);
    int efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    REQUIRE(efd >= 0);
    fap_port_options po;
    fap_port_options_init(&po);
    po.rs485_mode = FAP_RS485_NONE;
    po.write_timeout_us = 100000;
    REQUIRE(fap_port_open_cancellable(&p, name, &po, &efd) == 0);
    static uint8_t big[256];
    ssize_t r;
    int n = 0;
    do                           /* fill the pty until a write times out */
        r = fap_port_send(p, big, sizeof big);
    while (r == (ssize_t)sizeof big && ++n < 100000);
    CHECK_EQ(r, -ETIMEDOUT);
    uint64_t one = 1;
    REQUIRE(write(efd, &one, sizeof one) == sizeof one);
    int64_t t0 = fap_port_now_ns();      /* the same wait for room, now cancelled */
    CHECK_EQ(fap_port_send(p, big, sizeof big), -ECANCELED);
    CHECK(fap_port_now_ns() - t0 < CLOSE_BOUND_NS);
    fap_port_close(p);
    close(efd);
    close(peer);
}

UNIT_MAIN(UNIT(test_fapx_close_nobody_reading), UNIT(test_fapx_close_reader_200_bps),
          UNIT(test_exec_master_stop_ends_transaction), UNIT(test_port_cancellable_write))
