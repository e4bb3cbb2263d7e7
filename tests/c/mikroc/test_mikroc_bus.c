/* A mikroC master and two slaves over the virtual bus (ptys, relay thread,
 * echo on like a 2-wire bus). The master runs the vendor routines in the
 * main thread; each slave is a thread with its own context and port.
 * Synchronisation: condition variables and reads with deadlines only. */
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <time.h>

#include "fap_vbus.h"
#include "mikroc_rs485.h"
#include "unit.h"

#define WAIT_MS 5000               /* generous: only hit when something is broken */
#define CMD_CORRUPT_REPLY 0xC0     /* request: reply with a frame damaged on the wire */
#define CMD_NO_REPLY 0xC1          /* request: do not answer */

typedef struct slave_log {
    unsigned frames, errors, broadcasts;
    uint8_t last[3], last_count;
} slave_log;

typedef struct slave_node {
    unsigned port_index;
    uint8_t address;
    fap_vbus *bus;
    fap_port *port;
    mikrocRS485_ctx ctx;
    pthread_t thread;
    int started;
    atomic_int stop;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    slave_log log;               /* under mu */
} slave_node;

static fap_vbus *bus;
static fap_port *mport;
static slave_node slaves[2];

static int64_t deadline_in(int ms)
{
    return fap_port_now_ns() + (int64_t)ms * 1000000;
}

/* Read exactly n bytes or fail at the deadline. */
static int read_exact(fap_port *p, uint8_t *buf, size_t n, int ms)
{
    int64_t dl = deadline_in(ms);
    size_t got = 0;
    while (got < n) {
        ssize_t r = fap_port_read(p, buf + got, n - got, dl);
        if (r <= 0)
            return r < 0 ? (int)r : -ETIMEDOUT;
        got += (size_t)r;
    }
    return 0;
}

/* Write a frame so that its byte at index `at` is corrupted on the wire:
 * send the bytes before it, wait for their echo (the relay has passed
 * them), arm the fault, send the rest. */
static int write_corrupted(fap_port *p, unsigned port_index, const uint8_t *fr,
                           size_t n, size_t at)
{
    uint8_t echo[8];
    if (fap_port_write(p, fr, at) != (ssize_t)at)
        return -EIO;
    int r = read_exact(p, echo, at, WAIT_MS);
    if (r < 0)
        return r;
    fap_vbus_corrupt_next(bus, port_index, 1);
    /* our own echo of the rest is read by the context and ignored (direction) */
    return fap_port_write(p, fr + at, n - at) == (ssize_t)(n - at) ? 0 : -EIO;
}

static void *slave_main(void *arg)
{
    slave_node *s = arg;
    char buf[6] = {0};
    while (!atomic_load(&s->stop)) {
        int r = mikrocRS485_CtxPoll(&s->ctx, buf, 20);
        if (r <= 0)
            continue;
        /* the application reads, then clears the flags */
        uint8_t data[3], count = (uint8_t)buf[3];
        memcpy(data, buf, 3);
        int is_ready = (uint8_t)buf[4] == 255, is_error = (uint8_t)buf[5] == 255;
        buf[4] = buf[5] = 0;
        mikrocRS485_stats st;
        mikrocRS485_CtxGetStats(&s->ctx, &st);
        int broadcast = is_ready && st.last_address == MIKROC_RS485_BROADCAST &&
                        s->address != MIKROC_RS485_BROADCAST;
        pthread_mutex_lock(&s->mu);
        if (is_error)
            s->log.errors++;
        if (is_ready) {
            s->log.frames++;
            s->log.broadcasts += (unsigned)broadcast;
            memcpy(s->log.last, data, 3);
            s->log.last_count = count;
        }
        pthread_cond_broadcast(&s->cv);
        pthread_mutex_unlock(&s->mu);
        if (!is_ready || broadcast || (count && data[0] == CMD_NO_REPLY))
            continue;
        /* answer: each byte + 1, and our address as the last byte */
        char reply[3];
        unsigned n = count < 3 ? count + 1u : 3u;
        for (unsigned i = 0; i + 1 < n; i++)
            reply[i] = (char)(data[i] + 1);
        reply[n - 1] = (char)s->address;
        if (count && data[0] == CMD_CORRUPT_REPLY) {
            uint8_t fr[8];
            int len = mikrocRS485_Encode(fr, (const uint8_t *)reply, n, s->address, 0);
            write_corrupted(s->port, s->port_index, fr, (size_t)len, 3);
        } else {
            mikrocRS485_CtxSend(&s->ctx, reply, n, 0);
        }
    }
    return NULL;
}

/* Wait until pred(log) holds; returns 1, or 0 after WAIT_MS. */
static int slave_wait(slave_node *s, int (*pred)(const slave_log *, unsigned), unsigned arg)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    ts.tv_sec += WAIT_MS / 1000;
    pthread_mutex_lock(&s->mu);
    int rc = 0;
    while (!pred(&s->log, arg) && rc == 0)
        rc = pthread_cond_timedwait(&s->cv, &s->mu, &ts);
    int ok = pred(&s->log, arg);
    pthread_mutex_unlock(&s->mu);
    return ok;
}

static slave_log slave_snapshot(slave_node *s)
{
    pthread_mutex_lock(&s->mu);
    slave_log l = s->log;
    pthread_mutex_unlock(&s->mu);
    return l;
}

static int errors_at_least(const slave_log *l, unsigned n) { return l->errors >= n; }
static int broadcasts_at_least(const slave_log *l, unsigned n) { return l->broadcasts >= n; }

static int open_node_port(fap_port **p, unsigned i)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.baud = 19200;
    o.rs485_mode = FAP_RS485_NONE;      /* a pty has no RS-485 ioctls */
    return fap_port_open(p, fap_vbus_port_path(bus, i), &o);
}

static void setup(void)
{
    fap_vbus_options vo;
    fap_vbus_options_init(&vo);
    vo.n_ports = 3;
    vo.echo = 1;                        /* 2-wire: everyone hears themselves */
    vo.seed = 42;
    /* REQUIRE evaluates its argument twice: no side effects inside */
    int r = fap_vbus_open(&bus, &vo);
    REQUIRE(r == 0);
    r = open_node_port(&mport, 0);
    REQUIRE(r == 0);
    static const uint8_t addr[2] = {0x12, 150};   /* 150 travels escaped */
    for (unsigned k = 0; k < 2; k++) {
        slave_node *s = &slaves[k];
        memset(s, 0, sizeof *s);
        s->port_index = k + 1;
        s->address = addr[k];
        s->bus = bus;
        r = open_node_port(&s->port, k + 1);
        REQUIRE(r == 0);
        mikrocRS485_CtxInitSlave(&s->ctx, s->address);
        mikrocRS485_CtxBind(&s->ctx, s->port);
        pthread_mutex_init(&s->mu, NULL);
        pthread_cond_init(&s->cv, NULL);
        r = pthread_create(&s->thread, NULL, slave_main, s);
        REQUIRE(r == 0);
        s->started = 1;
    }
    /* the vendor routines, bound to the master's port */
    RS485Master_Init();
    mikrocRS485_Bind(mport);
}

static void teardown(void)
{
    for (unsigned k = 0; k < 2; k++) {
        if (!slaves[k].started)
            continue;
        atomic_store(&slaves[k].stop, 1);
        pthread_join(slaves[k].thread, NULL);
        fap_port_close(slaves[k].port);
        pthread_mutex_destroy(&slaves[k].mu);
        pthread_cond_destroy(&slaves[k].cv);
    }
    mikrocRS485_Bind(NULL);
    fap_port_close(mport);
    fap_vbus_close(bus);
}

/* Send a request the vendor way and wait for the master's flags. */
static int request(char *mbuf, const char *data, char len, uint8_t addr)
{
    memset(mbuf, 0, 7);
    RS485Master_Send((char *)data, len, (char)addr);
    if (mikrocRS485_LastSendError(1) != 0)
        return mikrocRS485_LastSendError(1);
    return mikrocRS485_Poll(mbuf, 1, WAIT_MS);
}

static void test_data_both_ways(void)
{
    char mbuf[7];
    /* to 0x12: {1,2} -> {2,3,0x12} */
    CHECK_EQ(request(mbuf, "\x01\x02", 2, 0x12), MIKROC_RS485_POLL_READY);
    CHECK_MEM(mbuf, "\x02\x03\x12\x03", 4);
    CHECK_EQ(mbuf[6], 0x12);
    /* to 150 (escaped address) with marker data: {0x96,0xA9} -> {0x97,0xAA,150} */
    CHECK_EQ(request(mbuf, "\x96\xA9", 2, 150), MIKROC_RS485_POLL_READY);
    CHECK_MEM(mbuf, "\x97\xAA\x96\x03", 4);
    CHECK_EQ((uint8_t)mbuf[6], 150);
    /* three bytes and no bytes */
    CHECK_EQ(request(mbuf, "\xA8\x95\x00", 3, 0x12), MIKROC_RS485_POLL_READY);
    CHECK_MEM(mbuf, "\xA9\x96\x12\x03", 4);
    CHECK_EQ(request(mbuf, "", 0, 150), MIKROC_RS485_POLL_READY);
    CHECK_EQ((uint8_t)mbuf[0], 150);
    CHECK_EQ(mbuf[3], 1);
    /* every exchange went to its slave only */
    slave_log a = slave_snapshot(&slaves[0]), b = slave_snapshot(&slaves[1]);
    CHECK_EQ(a.frames, 2);
    CHECK_EQ(b.frames, 2);
    CHECK_EQ(a.errors + b.errors, 0);
}

static void test_broadcast_reaches_slaves_except_150(void)
{
    char mbuf[7] = {0};
    slave_log a0 = slave_snapshot(&slaves[0]), b0 = slave_snapshot(&slaves[1]);
    RS485Master_Send("\x55", 1, MIKROC_RS485_BROADCAST);
    CHECK_EQ(mikrocRS485_LastSendError(1), 0);
    CHECK(slave_wait(&slaves[0], broadcasts_at_least, a0.broadcasts + 1));
    /* slave 150 must not take it: an exchange with it after the broadcast
     * proves it has processed the broadcast bytes by then */
    CHECK_EQ(request(mbuf, "\x01", 1, 150), MIKROC_RS485_POLL_READY);
    slave_log b = slave_snapshot(&slaves[1]);
    CHECK_EQ(b.broadcasts, b0.broadcasts);
    CHECK_EQ(b.frames, b0.frames + 1);
    CHECK_EQ(slave_snapshot(&slaves[0]).last[0], 0x55);
}

static void test_other_address_never_ready(void)
{
    char mbuf[7] = {0};
    slave_log a0 = slave_snapshot(&slaves[0]), b0 = slave_snapshot(&slaves[1]);
    for (unsigned addr = 0; addr < 256; addr += 7) {
        if (addr == 0x12 || addr == 150 || addr == MIKROC_RS485_BROADCAST)
            continue;
        RS485Master_Send("\x01\x02\x03", 3, (char)addr);
        CHECK_EQ(mikrocRS485_LastSendError(1), 0);
    }
    /* exchanges with both slaves afterwards: the frames before were seen */
    CHECK_EQ(request(mbuf, "\x07", 1, 0x12), MIKROC_RS485_POLL_READY);
    CHECK_EQ(request(mbuf, "\x07", 1, 150), MIKROC_RS485_POLL_READY);
    slave_log a = slave_snapshot(&slaves[0]), b = slave_snapshot(&slaves[1]);
    CHECK_EQ(a.frames, a0.frames + 1);
    CHECK_EQ(b.frames, b0.frames + 1);
    CHECK_EQ(a.errors, a0.errors);
    CHECK_EQ(b.errors, b0.errors);
}

/* A master frame damaged on the wire: its slave gets the error flag (and
 * no ready); the other slave nothing. */
static void test_corrupted_request_sets_slave_error(void)
{
    char mbuf[7] = {0};
    slave_log a0 = slave_snapshot(&slaves[0]), b0 = slave_snapshot(&slaves[1]);
    uint8_t fr[8];
    int n = mikrocRS485_Encode(fr, (const uint8_t *)"\x01", 1, 0x12, 1);
    REQUIRE(n == 6);
    /* the master port's own echo would land in the global context: the
     * frame is written with the raw port, its echo read in write_corrupted,
     * the rest ignored by the master (direction) */
    CHECK_EQ(write_corrupted(mport, 0, fr, (size_t)n, 3), 0);
    CHECK(slave_wait(&slaves[0], errors_at_least, a0.errors + 1));
    /* the bus still works, and nothing reached the wrong place */
    CHECK_EQ(request(mbuf, "\x02", 1, 0x12), MIKROC_RS485_POLL_READY);
    CHECK_EQ(request(mbuf, "\x02", 1, 150), MIKROC_RS485_POLL_READY);
    slave_log a = slave_snapshot(&slaves[0]), b = slave_snapshot(&slaves[1]);
    CHECK_EQ(a.frames, a0.frames + 1);        /* the damaged one never ready */
    CHECK_EQ(b.errors, b0.errors);
    CHECK_EQ(b.frames, b0.frames + 1);
}

/* A slave reply damaged on the wire: the master's error flag, no ready. */
static void test_corrupted_reply_sets_master_error(void)
{
    char mbuf[7];
    CHECK_EQ(request(mbuf, "\xC0\x05", 2, 150), MIKROC_RS485_POLL_ERROR);
    CHECK_EQ((uint8_t)mbuf[5], 255);
    CHECK_EQ(mbuf[4], 0);
    int e = mikrocRS485_LastRxError(1);
    CHECK(e == MIKROC_RS485_ECRC || e == MIKROC_RS485_EFORMAT || e == MIKROC_RS485_ESHORT ||
          e == MIKROC_RS485_ELONG || e == MIKROC_RS485_EABORT);
    /* and the next exchange is clean */
    CHECK_EQ(request(mbuf, "\x01", 1, 150), MIKROC_RS485_POLL_READY);
}

static void test_receive_nonblocking_and_timeout(void)
{
    char mbuf[7] = {0};
    /* nothing on the bus: Receive does nothing, Poll(0) returns 0 at once */
    RS485Master_Receive(mbuf);
    CHECK_EQ(mbuf[4], 0);
    CHECK_EQ(mikrocRS485_Poll(mbuf, 1, 0), 0);
    /* a request nobody answers: Poll times out with 0 */
    RS485Master_Send("\xC1", 1, 0x12);
    CHECK_EQ(mikrocRS485_Poll(mbuf, 1, 30), 0);
    /* the vendor loop: the fd turning readable stands for the UART
     * interrupt; Receive takes one byte per call */
    RS485Master_Send("\x09", 1, 0x12);
    int64_t dl = deadline_in(WAIT_MS);
    unsigned calls = 0;
    while ((uint8_t)mbuf[4] != 255 && fap_port_now_ns() < dl) {
        struct pollfd pf = {.fd = fap_port_fd(mport), .events = POLLIN};
        if (poll(&pf, 1, 100) == 1) {
            RS485Master_Receive(mbuf);
            calls++;
        }
    }
    /* our own request's echo (6 bytes) and the reply (6 bytes) */
    CHECK(calls >= 12);
    CHECK_EQ((uint8_t)mbuf[4], 255);
    CHECK_MEM(mbuf, "\x0A\x12\x00\x02", 4);
}

static void test_send_rejects_long_data(void)
{
    char mbuf[7] = {0};
    RS485Master_Send("\x01\x02\x03\x04", 4, 0x12);
    CHECK_EQ(mikrocRS485_LastSendError(1), -EINVAL);
    /* nothing went out: the next exchange is the only traffic */
    CHECK_EQ(request(mbuf, "\x04", 1, 0x12), MIKROC_RS485_POLL_READY);
    CHECK_MEM(mbuf, "\x05\x12\x00\x02", 4);
}

int main(void)
{
    setup();
    if (!bus || !mport || !slaves[0].started || !slaves[1].started) {
        printf("%d passed, %d failed\n", unit_passed, unit_failed + 1);
        return 1;
    }
    static const unit_test tests[] = {
        UNIT(test_data_both_ways),
        UNIT(test_broadcast_reaches_slaves_except_150),
        UNIT(test_other_address_never_ready),
        UNIT(test_corrupted_request_sets_slave_error),
        UNIT(test_corrupted_reply_sets_master_error),
        UNIT(test_receive_nonblocking_and_timeout),
        UNIT(test_send_rejects_long_data),
    };
    int rc = unit_run(tests, sizeof tests / sizeof tests[0]);
    teardown();
    return rc;
}
