/* Exec async master + 3 slaves on the virtual bus (ptys, relay thread).
 * Ports: 0 master, 1..3 slaves (nodes 1..3, each served by its own thread),
 * 4 a raw port the tests use to inject frames, 5 a spy that records the
 * wire. Slave handlers count what they apply, so a retry that re-ran the
 * handler would show. */
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <semaphore.h>
#include <stdio.h>
#include <time.h>

#include "exec_async_engine.h"
#include "fap_vbus.h"
#include "unit.h"
#include "exec_echo.h"

#define N_SLAVES 3
#define PORT_MASTER 0
#define PORT_RAW 4
#define PORT_SPY 5

/* unit.h's REQUIRE evaluates its argument twice: call first, then check. */
#define REQUIRE_ZERO(expr) do { long long rz_ = (long long)(expr); REQUIRE(rz_ == 0); } while (0)

typedef struct slave_ctx {
    execSlave *slave;
    pthread_t thread;
    byte node;
    unsigned applied;          /* atomic: requests the handler applied */
    unsigned broadcasts;       /* atomic */
    int intrude;               /* atomic: 1 = inject a frame while handling */
    int serve_result;          /* how the thread ended */
} slave_ctx;

static fap_vbus *bus;
static execMaster *master;
static slave_ctx slaves[N_SLAVES];
static fap_port *raw, *spy;
static sem_t bcast_sem;

static unsigned load(unsigned *p) { return __atomic_load_n(p, __ATOMIC_ACQUIRE); }
static void inc(unsigned *p) { __atomic_fetch_add(p, 1, __ATOMIC_ACQ_REL); }

/* Reply: node, the applied count after this request, then the request. */
static int handler(void *vctx, const execSlaveRequest *req, byte *reply, word cap)
{
    slave_ctx *c = vctx;
    if (req->node == EXEC_ASYNC_BROADCAST) {
        inc(&c->broadcasts);
        sem_post(&bcast_sem);
        return 0;
    }
    int intrude = __atomic_exchange_n(&c->intrude, 0, __ATOMIC_ACQ_REL);
    if (intrude) {
        /* another master frame arrives before our reply goes out
         * (1: a request for us, 2: a broadcast) */
        byte data[] = "intruder";
        byte f[64];
        word n = execAsyncBufferOut(intrude == 2 ? EXEC_ASYNC_BROADCAST : c->node, data, f, 8, 200);
        fap_port_write(raw, f, n);
        struct pollfd pf = {.fd = fap_port_fd(execSlavePort(c->slave)), .events = POLLIN};
        poll(&pf, 1, 2000);   /* wait for it to reach us, not for a time */
    }
    inc(&c->applied);
    if (req->len + 2u > cap)
        return -1;
    reply[0] = c->node;
    reply[1] = (byte)load(&c->applied);
    memcpy(reply + 2, req->data, req->len);
    return req->len + 2;
}

static void *serve_thread(void *arg)
{
    slave_ctx *c = arg;
    int r;
    while ((r = execSlaveServe(c->slave, -1)) >= 0)
        ;
    c->serve_result = r;
    return NULL;
}

static int64_t now_ns(void)
{
    return fap_port_now_ns();
}

/* Read whatever the spy saw until `ms` of silence; decode it. */
typedef struct seen_frame { byte node, seq, status; word len; byte data[256]; } seen_frame;

static size_t spy_frames(seen_frame *out, size_t max, int quiet_ms)
{
    struct execAsyncStateDef st;
    memset(&st, 0, sizeof st);
    byte buf[EXEC_ASYNC_MAX_DATA];
    size_t n = 0;
    byte chunk[512];
    for (;;) {
        ssize_t r = fap_port_read(spy, chunk, sizeof chunk, now_ns() + quiet_ms * 1000000LL);
        if (r <= 0)
            break;
        for (ssize_t i = 0; i < r; i++) {
            if (execAsyncByteIn(chunk[i], &st, buf) && n < max) {
                out[n].node = st.Node;
                out[n].seq = st.SeqNo;
                out[n].status = st.Status;
                out[n].len = st.Length;
                memcpy(out[n].data, buf, st.Length);
                n++;
            }
        }
    }
    return n;
}

static void spy_drain(void)
{
    seen_frame tmp[64];
    (void)spy_frames(tmp, 64, 5);
}

static fap_port_options port_opts(void)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = FAP_RS485_NONE;
    return o;
}

static int setup(void)
{
    sem_init(&bcast_sem, 0, 0);
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    bo.n_ports = 6;
    int err = fap_vbus_open(&bus, &bo);
    if (err) {
        fprintf(stderr, "fap_vbus_open: %d\n", err);
        return err;
    }
    fap_port_options po = port_opts();
    execMasterOptions mo;
    execMasterOptionsInit(&mo);
    /* 1 s: a loaded machine (sanitizers, parallel runs) must not cause a
     * retry the tests do not expect (a retried seq 0 is processed again, by
     * the settled rule); tests that lose a reply on purpose shorten it. */
    mo.reply_timeout_us = 1000000;
    mo.retries = 5;
    err = execMasterOpen(&master, fap_vbus_port_path(bus, PORT_MASTER), &po, &mo);
    if (err)
        return err;
    for (int i = 0; i < N_SLAVES; i++) {
        slave_ctx *c = &slaves[i];
        c->node = (byte)(i + 1);
        execSlaveOptions so;
        execSlaveOptionsInit(&so);
        so.node = c->node;
        err = execSlaveOpen(&c->slave, fap_vbus_port_path(bus, (unsigned)(i + 1)), &po, &so,
                            handler, c);
        if (err)
            return err;
        pthread_create(&c->thread, NULL, serve_thread, c);
    }
    err = fap_port_open(&raw, fap_vbus_port_path(bus, PORT_RAW), &po);
    if (!err)
        err = fap_port_open(&spy, fap_vbus_port_path(bus, PORT_SPY), &po);
    return err;
}

static void test_teardown(void)
{
    for (int i = 0; i < N_SLAVES; i++) {
        execSlaveStop(slaves[i].slave);
        pthread_join(slaves[i].thread, NULL);
        CHECK_EQ(slaves[i].serve_result, -ECANCELED);
        execSlaveClose(slaves[i].slave);
    }
    execMasterClose(master);
    fap_port_close(raw);
    fap_port_close(spy);
    fap_vbus_close(bus);
    sem_destroy(&bcast_sem);
}

static int transact_str(byte node, const char *s, byte *reply, word *rlen)
{
    return execMasterTransact(master, node, (const byte *)s, (word)strlen(s), reply, 255, rlen);
}

static void test_poll_each_slave(void)
{
    spy_drain();
    for (int round = 0; round < 3; round++) {
        for (byte node = 1; node <= N_SLAVES; node++) {
            unsigned before = load(&slaves[node - 1].applied);
            CHECK_EQ(execMasterNextSeq(master, node), round);   /* 0, 1, 2 per node */
            byte reply[255];
            word rlen = 0;
            int err = transact_str(node, "ping\x10", reply, &rlen);
            REQUIRE(err == 0);
            CHECK_EQ(rlen, 7);
            CHECK_EQ(reply[0], node);
            CHECK_EQ(reply[1], before + 1);
            CHECK_MEM(reply + 2, "ping\x10", 5);
            CHECK_EQ(load(&slaves[node - 1].applied), before + 1);
        }
    }
    /* on the wire: request and reply carry the same node and seq */
    seen_frame f[32];
    size_t n = spy_frames(f, 32, 20);
    CHECK_EQ(n, 18);
    for (size_t i = 0; i + 1 < n; i += 2) {
        CHECK_EQ(f[i].status, EXEC_ASYNC_GOOD);
        CHECK_EQ(f[i + 1].status, EXEC_ASYNC_GOOD);
        CHECK_EQ(f[i].node, f[i + 1].node);
        CHECK_EQ(f[i].seq, f[i + 1].seq);
        CHECK_EQ(f[i].seq, i / 6);
    }
}

/* The bus loses slave 2's reply: the master retries with the same seq, the
 * slave resends its reply without running the handler again. */
static void test_dropped_reply_applied_once(void)
{
    slave_ctx *c = &slaves[1];
    unsigned before = load(&c->applied);
    execSlaveStats s0;
    execSlaveGetStats(c->slave, &s0);
    execMasterStats m0;
    execMasterGetStats(master, &m0);
    int seq = execMasterNextSeq(master, 2);
    /* the reply will be: node, count, "once" -> its exact frame length */
    byte expect[6] = {2, (byte)(before + 1), 'o', 'n', 'c', 'e'};
    byte frame[32];
    word flen = execAsyncBufferOut(2, expect, frame, 6, (byte)seq);
    REQUIRE_ZERO(execMasterSetTimeout(master, 50000, 5));
    REQUIRE_ZERO(fap_vbus_drop_next(bus, 2, flen));

    byte reply[255];
    word rlen = 0;
    CHECK_EQ(transact_str(2, "once", reply, &rlen), 0);
    CHECK_EQ(rlen, 6);
    CHECK_MEM(reply, expect, 6);              /* the original reply, unchanged */
    CHECK_EQ(load(&c->applied), before + 1);  /* applied exactly once */
    execSlaveStats s1;
    execSlaveGetStats(c->slave, &s1);
    CHECK_EQ(s1.processed, s0.processed + 1);
    CHECK(s1.resent >= s0.resent + 1);
    execMasterStats m1;
    execMasterGetStats(master, &m1);
    CHECK(m1.retries >= m0.retries + 1);
    CHECK(m1.timeouts >= m0.timeouts + 1);
    CHECK_EQ(m1.replies, m0.replies + 1);
    CHECK_EQ(execMasterNextSeq(master, 2), seq == 255 ? 1 : seq + 1);
    REQUIRE_ZERO(execMasterSetTimeout(master, 1000000, 5));
}

/* Sequence number 0 means start-up: always processed, even as a retry
 * (the settled rule); a master restart is what sends it. */
static void test_retried_seq_zero_processed_again(void)
{
    slave_ctx *c = &slaves[1];
    execMasterResetSequence(master);
    CHECK_EQ(execMasterNextSeq(master, 2), 0);
    unsigned before = load(&c->applied);
    byte expect[6] = {2, (byte)(before + 1), 'b', 'o', 'o', 't'};
    byte frame[32];
    word flen = execAsyncBufferOut(2, expect, frame, 6, 0);
    REQUIRE_ZERO(execMasterSetTimeout(master, 200000, 5));
    REQUIRE_ZERO(fap_vbus_drop_next(bus, 2, flen));
    byte reply[255];
    word rlen = 0;
    CHECK_EQ(transact_str(2, "boot", reply, &rlen), 0);
    CHECK_EQ(load(&c->applied), before + 2);
    CHECK_EQ(reply[1], before + 2);
    CHECK_EQ(transact_str(2, "seq1", reply, &rlen), 0);   /* 1 after 0: new, processed */
    CHECK_EQ(load(&c->applied), before + 3);
    REQUIRE_ZERO(execMasterSetTimeout(master, 1000000, 5));
}

/* A fake slave on the raw port answers node 9 first with a corrupted reply:
 * the master's CRC check catches it and it asks again with the same seq. */
typedef struct fake_ctx { int seqs[4]; int n; } fake_ctx;

static void *fake_slave(void *arg)
{
    fake_ctx *fc = arg;
    struct execAsyncStateDef st;
    memset(&st, 0, sizeof st);
    byte buf[EXEC_ASYNC_MAX_DATA], chunk[256];
    int64_t deadline = now_ns() + 3000000000LL;
    while (fc->n < 2 && now_ns() < deadline) {
        ssize_t r = fap_port_read(raw, chunk, sizeof chunk, deadline);
        if (r <= 0)
            break;
        for (ssize_t i = 0; i < r; i++) {
            if (!execAsyncByteIn(chunk[i], &st, buf) || st.Node != 9 || st.Status != EXEC_ASYNC_GOOD)
                continue;
            fc->seqs[fc->n++] = st.SeqNo;
            byte f[64];
            byte data[] = {'o', 'k'};
            word n = execAsyncBufferOut(9, data, f, 2, st.SeqNo);
            if (fc->n == 1)
                f[4] ^= 0x01;   /* one bit of the data: only the CRC can tell */
            fap_port_write(raw, f, n);
        }
    }
    return NULL;
}

static void test_corrupt_reply_caught_by_crc(void)
{
    fake_ctx fc = {{0}, 0};
    fap_port_flush(raw);   /* earlier traffic */
    pthread_t t;
    pthread_create(&t, NULL, fake_slave, &fc);
    execMasterStats m0;
    execMasterGetStats(master, &m0);
    byte reply[255];
    word rlen = 0;
    int err = transact_str(9, "x", reply, &rlen);
    pthread_join(t, NULL);
    CHECK_EQ(err, 0);
    CHECK_EQ(rlen, 2);
    CHECK_MEM(reply, "ok", 2);
    CHECK_EQ(fc.n, 2);
    CHECK_EQ(fc.seqs[0], 0);
    CHECK_EQ(fc.seqs[1], 0);      /* the retry keeps the sequence number */
    execMasterStats m1;
    execMasterGetStats(master, &m1);
    CHECK_EQ(m1.corrupt, m0.corrupt + 1);
    CHECK(m1.retries >= m0.retries + 1);
}

/* A corrupted request is dropped by the slave (CRC) and never applied. */
static void test_corrupt_request_ignored(void)
{
    slave_ctx *c = &slaves[0];
    byte reply[255];
    word rlen;
    /* once slave 1 has answered this, it has decoded all earlier traffic */
    CHECK_EQ(transact_str(1, "sync", reply, &rlen), 0);
    unsigned before = load(&c->applied);
    execSlaveStats s0;
    execSlaveGetStats(c->slave, &s0);
    spy_drain();
    byte data[] = "bad";
    byte f[32];
    word n = execAsyncBufferOut(1, data, f, 3, 77);
    f[5] ^= 0x40;
    REQUIRE_ZERO(fap_port_write(raw, f, n) - n);
    /* once the spy has it, the relay has passed it to every port */
    seen_frame sf[4];
    CHECK_EQ(spy_frames(sf, 4, 20), 1);
    CHECK_EQ(sf[0].status, EXEC_ASYNC_BAD_CRC);
    CHECK_EQ(transact_str(1, "good", reply, &rlen), 0);   /* served after the bad one */
    CHECK_EQ(load(&c->applied), before + 1);
    execSlaveStats s1;
    execSlaveGetStats(c->slave, &s1);
    CHECK_EQ(s1.corrupt, s0.corrupt + 1);
    CHECK_EQ(s1.processed, s0.processed + 1);
}

static void test_broadcast_reaches_all_nobody_answers(void)
{
    spy_drain();
    execSlaveStats s0[N_SLAVES];
    for (int i = 0; i < N_SLAVES; i++)
        execSlaveGetStats(slaves[i].slave, &s0[i]);
    byte data[] = {0xB0, 0x10, 0x0C};
    CHECK_EQ(execMasterBroadcast(master, data, 3), 0);
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    ts.tv_sec += 3;
    for (int i = 0; i < N_SLAVES; i++)
        CHECK_EQ(sem_timedwait(&bcast_sem, &ts), 0);
    /* one more poll each: every slave has finished with the broadcast */
    for (byte node = 1; node <= N_SLAVES; node++) {
        byte reply[255];
        word rlen;
        CHECK_EQ(transact_str(node, "after", reply, &rlen), 0);
    }
    seen_frame f[16];
    size_t n = spy_frames(f, 16, 20);
    CHECK_EQ(n, 1 + 2 * N_SLAVES);   /* the broadcast, then request/reply pairs only */
    CHECK_EQ(f[0].node, 255);
    CHECK_EQ(f[0].len, 3);
    CHECK_MEM(f[0].data, data, 3);
    for (int i = 0; i < N_SLAVES; i++) {
        execSlaveStats s;
        execSlaveGetStats(slaves[i].slave, &s);
        CHECK_EQ(s.broadcasts, s0[i].broadcasts + 1);
        CHECK_EQ(s.replies, s0[i].replies + 1);    /* the "after" reply only */
        CHECK_EQ(load(&slaves[i].broadcasts), 1);
    }
}

/* A frame that arrives while slave 3 is answering is not answered. */
static void test_message_during_reply_not_answered(void)
{
    slave_ctx *c = &slaves[2];
    unsigned before = load(&c->applied);
    execSlaveStats s0;
    execSlaveGetStats(c->slave, &s0);
    execMasterStats m0;
    execMasterGetStats(master, &m0);
    __atomic_store_n(&c->intrude, 1, __ATOMIC_RELEASE);
    byte reply[255];
    word rlen;
    CHECK_EQ(transact_str(3, "main", reply, &rlen), 0);
    CHECK_EQ(rlen, 6);
    CHECK_MEM(reply + 2, "main", 4);
    CHECK_EQ(transact_str(3, "next", reply, &rlen), 0);   /* the slave is in step */
    CHECK_MEM(reply + 2, "next", 4);
    CHECK_EQ(load(&c->applied), before + 2);              /* not the intruder */
    execSlaveStats s1;
    execSlaveGetStats(c->slave, &s1);
    CHECK_EQ(s1.rx_during_tx, s0.rx_during_tx + 1);
    execMasterStats m1;
    execMasterGetStats(master, &m1);
    CHECK_EQ(m1.unexpected, m0.unexpected + 1);   /* the master saw it too and kept waiting */
}

/* A broadcast in that window is still processed (never answered anyway). */
static void test_broadcast_during_reply_processed(void)
{
    slave_ctx *c = &slaves[2];
    execSlaveStats s0;
    execSlaveGetStats(c->slave, &s0);
    __atomic_store_n(&c->intrude, 2, __ATOMIC_RELEASE);
    byte reply[255];
    word rlen;
    CHECK_EQ(transact_str(3, "main", reply, &rlen), 0);
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    ts.tv_sec += 3;
    for (int i = 0; i < N_SLAVES; i++)
        CHECK_EQ(sem_timedwait(&bcast_sem, &ts), 0);   /* every slave, slave 3 included */
    execSlaveStats s1;
    execSlaveGetStats(c->slave, &s1);
    CHECK_EQ(s1.broadcasts, s0.broadcasts + 1);
    CHECK_EQ(s1.rx_during_tx, s0.rx_during_tx);
}

static void test_absent_node_times_out(void)
{
    REQUIRE_ZERO(execMasterSetTimeout(master, 5000, 2));
    execMasterStats m0;
    execMasterGetStats(master, &m0);
    byte reply[8];
    word rlen = 99;
    CHECK_EQ(execMasterTransact(master, 77, (const byte *)"?", 1, reply, 8, &rlen), -ETIMEDOUT);
    CHECK_EQ(rlen, 0);
    execMasterStats m1;
    execMasterGetStats(master, &m1);
    CHECK_EQ(m1.timeouts, m0.timeouts + 3);
    CHECK_EQ(m1.retries, m0.retries + 2);
    CHECK_EQ(m1.failures, m0.failures + 1);
    /* a failed transaction restarts the node at 0 (no stale reply after a wrap) */
    CHECK_EQ(execMasterNextSeq(master, 77), 0);
    CHECK_EQ(execMasterTransact(master, 77, (const byte *)"?", 1, reply, 8, &rlen), -ETIMEDOUT);
    CHECK_EQ(execMasterNextSeq(master, 77), 0);
    REQUIRE_ZERO(execMasterSetTimeout(master, 1000000, 5));
}

static void test_bad_arguments(void)
{
    byte big[300] = {0}, reply[4];
    word rlen = 0;
    CHECK_EQ(execMasterTransact(master, 0, big, 1, reply, 4, &rlen), -EINVAL);
    CHECK_EQ(execMasterTransact(master, 255, big, 1, reply, 4, &rlen), -EINVAL);
    CHECK_EQ(execMasterTransact(master, 1, big, 256, reply, 4, &rlen), -EMSGSIZE);
    CHECK_EQ(execMasterTransact(master, 1, NULL, 3, reply, 4, &rlen), -EINVAL);
    CHECK_EQ(execMasterBroadcast(master, big, 256), -EMSGSIZE);
    CHECK_EQ(execMasterTransact(NULL, 1, big, 1, reply, 4, &rlen), -EINVAL);
    /* a reply longer than the buffer: first bytes kept, full length told */
    unsigned before = load(&slaves[0].applied);
    CHECK_EQ(execMasterTransact(master, 1, (const byte *)"abcdef", 6, reply, 4, &rlen), -ENOBUFS);
    CHECK_EQ(rlen, 8);
    CHECK_EQ(reply[0], 1);
    CHECK_EQ(reply[1], before + 1);
    CHECK_MEM(reply + 2, "ab", 2);

    execSlave *s = NULL;
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    so.node = EXEC_ASYNC_NODE_MIN - 1;
    fap_port_options po = port_opts();
    CHECK_EQ(execSlaveOpen(&s, fap_vbus_port_path(bus, 1), &po, &so, handler, NULL), -EINVAL);
    so.node = EXEC_ASYNC_NODE_MAX + 1;
    CHECK_EQ(EXEC_ASYNC_NODE_MAX + 1, EXEC_ASYNC_BROADCAST);
    CHECK_EQ(execSlaveOpen(&s, fap_vbus_port_path(bus, 1), &po, &so, handler, NULL), -EINVAL);
    so.node = 4;
    CHECK(execSlaveOpen(&s, "/nonexistent/tty", &po, &so, handler, NULL) < 0);
    CHECK(s == NULL);
    execMaster *m = NULL;
    CHECK(execMasterOpen(&m, "/nonexistent/tty", &po, NULL) < 0);
    CHECK(m == NULL);
    CHECK_EQ(execSlaveServe(NULL, 0), -EINVAL);
    execMasterClose(NULL);
    execSlaveClose(NULL);
}

/* Turnaround: the slave waits out the port's quiet time before answering. */
static void *serve_until_stop(void *arg)
{
    while (execSlaveServe(arg, -1) >= 0)
        ;
    return NULL;
}

static void test_turnaround_delay(void)
{
    fap_vbus *b2;
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    bo.n_ports = 2;
    REQUIRE_ZERO(fap_vbus_open(&b2, &bo));
    fap_port_options po = port_opts();
    execMaster *m;
    execMasterOptions mo;
    execMasterOptionsInit(&mo);
    mo.reply_timeout_us = 1000000;   /* no retry on a loaded machine */
    REQUIRE_ZERO(execMasterOpen(&m, fap_vbus_port_path(b2, 0), &po, &mo));
    po.turnaround_us = 20000;
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    so.node = 42;
    execSlave *s;
    REQUIRE_ZERO(execSlaveOpen(&s, fap_vbus_port_path(b2, 1), &po, &so, test_exec_echo, NULL));
    pthread_t t;
    pthread_create(&t, NULL, serve_until_stop, s);
    for (int i = 0; i < 2; i++) {
        byte reply[8];
        word rlen;
        int64_t t0 = now_ns();
        CHECK_EQ(execMasterTransact(m, 42, (const byte *)"hi", 2, reply, 8, &rlen), 0);
        CHECK(now_ns() - t0 >= 20000000LL);   /* a lower bound, never a speed claim */
        CHECK_EQ(rlen, 2);
    }
    execMasterStats ms;
    execMasterGetStats(m, &ms);
    CHECK_EQ(ms.retries, 0);
    execSlaveStop(s);
    pthread_join(t, NULL);
    execSlaveClose(s);
    execMasterClose(m);
    fap_vbus_close(b2);
}

/* A port that vanishes: both ends get the port's error, promptly. */
static void test_port_vanishes(void)
{
    fap_vbus *b2;
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    REQUIRE_ZERO(fap_vbus_open(&b2, &bo));
    fap_port_options po = port_opts();
    execSlave *s;
    execMaster *m;
    REQUIRE_ZERO(execSlaveOpen(&s, fap_vbus_port_path(b2, 1), &po, NULL, test_exec_echo, NULL));
    REQUIRE_ZERO(execMasterOpen(&m, fap_vbus_port_path(b2, 0), &po, NULL));
    REQUIRE_ZERO(fap_vbus_disconnect(b2, 1, 300));
    REQUIRE_ZERO(fap_vbus_disconnect(b2, 0, 300));
    int64_t t0 = now_ns();
    int r = execSlaveServe(s, 5000);
    CHECK(r < 0 && r != -ECANCELED);
    byte reply[8];
    word rlen;
    int e = execMasterTransact(m, 1, (const byte *)"x", 1, reply, 8, &rlen);
    CHECK(e < 0 && e != -ETIMEDOUT);
    CHECK(now_ns() - t0 < 4000000000LL);   /* an error, not the 5 s wait */
    execMasterClose(m);
    execSlaveClose(s);
    fap_vbus_close(b2);
}

static void test_stop_wakes_serve(void)
{
    fap_vbus *b2;
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    REQUIRE_ZERO(fap_vbus_open(&b2, &bo));
    fap_port_options po = port_opts();
    execSlave *s;
    REQUIRE_ZERO(execSlaveOpen(&s, fap_vbus_port_path(b2, 1), &po, NULL, test_exec_echo, NULL));
    CHECK_EQ(execSlaveServe(s, 1), 0);        /* nothing there: time runs out */
    pthread_t t;
    pthread_create(&t, NULL, serve_until_stop, s);
    execSlaveStop(s);
    pthread_join(t, NULL);                    /* returns: Stop woke it */
    CHECK_EQ(execSlaveServe(s, -1), -ECANCELED);
    execSlaveClose(s);
    fap_vbus_close(b2);
}

/* ---- execMasterBegin/Step: what an event loop does, with poll() ---- */

static int step_loop(byte node, const char *s, byte *reply, word cap, word *rlen)
{
    int64_t deadline = 0;
    int rc = execMasterBegin(master, node, (const byte *)s, (word)strlen(s), &deadline);
    if (rc)
        return rc;
    CHECK(deadline > now_ns());
    struct pollfd p = {.fd = fap_port_fd(execMasterPort(master)), .events = POLLIN};
    for (;;) {
        int64_t left = deadline - now_ns();
        poll(&p, 1, left > 0 ? (int)((left + 999999) / 1000000) : 0);
        rc = execMasterStep(master, reply, cap, rlen, &deadline);
        if (rc != EXEC_MASTER_MORE)
            return rc;
    }
}

static void test_step_transaction(void)
{
    slave_ctx *c = &slaves[0];
    unsigned before = load(&c->applied);
    int seq = execMasterNextSeq(master, 1);
    execMasterStats m0;
    execMasterGetStats(master, &m0);
    byte reply[255];
    word rlen = 0;
    CHECK_EQ(step_loop(1, "step", reply, 255, &rlen), 0);
    CHECK_EQ(rlen, 6);
    CHECK_EQ(reply[0], 1);
    CHECK_EQ(reply[1], before + 1);
    CHECK_MEM(reply + 2, "step", 4);
    CHECK_EQ(execMasterNextSeq(master, 1), seq == 255 ? 1 : seq + 1);
    execMasterStats m1;
    execMasterGetStats(master, &m1);
    CHECK_EQ(m1.transactions, m0.transactions + 1);
    CHECK_EQ(m1.replies, m0.replies + 1);
    CHECK_EQ(m1.tx_frames, m0.tx_frames + 1);
    /* nothing in flight any more */
    CHECK_EQ(execMasterStep(master, reply, 255, &rlen, NULL), -EINVAL);
    /* a reply too long for the buffer: as execMasterTransact */
    CHECK_EQ(step_loop(1, "long", reply, 3, &rlen), -ENOBUFS);
    CHECK_EQ(rlen, 6);
    CHECK_MEM(reply, ((byte[]){1, (byte)(before + 2), 'l'}), 3);
}

/* One transaction at a time; Abort ends it as a failure (next SeqNo 0). */
static void test_step_busy_and_abort(void)
{
    byte reply[255];
    word rlen = 0;
    CHECK_EQ(step_loop(3, "a", reply, 255, &rlen), 0);
    CHECK(execMasterNextSeq(master, 3) != 0);
    execMasterStats m0;
    execMasterGetStats(master, &m0);
    int64_t d;
    REQUIRE_ZERO(execMasterBegin(master, 3, (const byte *)"b", 1, &d));
    CHECK_EQ(execMasterBegin(master, 2, (const byte *)"c", 1, &d), -EBUSY);
    execMasterAbort(master);
    execMasterAbort(master);                  /* nothing in flight: no-op */
    CHECK_EQ(execMasterNextSeq(master, 3), 0);
    execMasterStats m1;
    execMasterGetStats(master, &m1);
    CHECK_EQ(m1.failures, m0.failures + 1);
    CHECK_EQ(m1.transactions, m0.transactions + 1);
    /* the aborted request's reply may still come: flushed by the next Begin */
    CHECK_EQ(step_loop(3, "d", reply, 255, &rlen), 0);
    CHECK_MEM(reply + 2, "d", 1);
    CHECK_EQ(step_loop(0, "x", reply, 255, &rlen), -EINVAL);
    CHECK_EQ(step_loop(EXEC_ASYNC_BROADCAST, "x", reply, 255, &rlen), -EINVAL);
    CHECK_EQ(execMasterStep(NULL, reply, 255, &rlen, NULL), -EINVAL);
    CHECK_EQ(execMasterBegin(NULL, 1, NULL, 0, NULL), -EINVAL);
    execMasterAbort(NULL);
}

/* The reply is lost: Step resends with the same seq, the slave resends its
 * reply without applying the request twice. */
static void test_step_retry_after_dropped_reply(void)
{
    slave_ctx *c = &slaves[1];
    unsigned before = load(&c->applied);
    int seq = execMasterNextSeq(master, 2);
    byte expect[6] = {2, (byte)(before + 1), 'o', 'n', 'c', 'e'};
    byte frame[32];
    word flen = execAsyncBufferOut(2, expect, frame, 6, (byte)seq);
    execMasterStats m0;
    execMasterGetStats(master, &m0);
    REQUIRE_ZERO(execMasterSetTimeout(master, 50000, 5));
    REQUIRE_ZERO(fap_vbus_drop_next(bus, 2, flen));
    byte reply[255];
    word rlen = 0;
    CHECK_EQ(step_loop(2, "once", reply, 255, &rlen), 0);
    CHECK_EQ(rlen, 6);
    CHECK_MEM(reply, expect, 6);
    CHECK_EQ(load(&c->applied), before + 1);
    execMasterStats m1;
    execMasterGetStats(master, &m1);
    CHECK(m1.retries >= m0.retries + 1);
    CHECK(m1.timeouts >= m0.timeouts + 1);
    CHECK_EQ(m1.replies, m0.replies + 1);
    CHECK_EQ(execMasterNextSeq(master, 2), seq == 255 ? 1 : seq + 1);
    REQUIRE_ZERO(execMasterSetTimeout(master, 1000000, 5));
}

/* Every reply lost (no retries left): -ETIMEDOUT, and the node restarts at
 * SeqNo 0; an absent node times out after every attempt. */
static void test_step_timeout_seq_zero(void)
{
    slave_ctx *c = &slaves[1];
    byte reply[255];
    word rlen = 0;
    CHECK_EQ(step_loop(2, "warm", reply, 255, &rlen), 0);
    int seq = execMasterNextSeq(master, 2);
    CHECK(seq != 0);
    byte expect[6] = {2, (byte)(load(&c->applied) + 1), 'l', 'o', 's', 't'};
    byte frame[32];
    word flen = execAsyncBufferOut(2, expect, frame, 6, (byte)seq);
    REQUIRE_ZERO(execMasterSetTimeout(master, 50000, 0));
    REQUIRE_ZERO(fap_vbus_drop_next(bus, 2, flen));
    rlen = 99;
    CHECK_EQ(step_loop(2, "lost", reply, 255, &rlen), -ETIMEDOUT);
    CHECK_EQ(rlen, 0);
    CHECK_EQ(execMasterNextSeq(master, 2), 0);
    REQUIRE_ZERO(execMasterSetTimeout(master, 5000, 2));
    execMasterStats m0;
    execMasterGetStats(master, &m0);
    CHECK_EQ(step_loop(78, "?", reply, 255, &rlen), -ETIMEDOUT);
    execMasterStats m1;
    execMasterGetStats(master, &m1);
    CHECK_EQ(m1.timeouts, m0.timeouts + 3);
    CHECK_EQ(m1.retries, m0.retries + 2);
    CHECK_EQ(m1.failures, m0.failures + 1);
    CHECK_EQ(execMasterNextSeq(master, 78), 0);
    REQUIRE_ZERO(execMasterSetTimeout(master, 1000000, 5));
    /* and the node answers seq 0 afresh */
    CHECK_EQ(step_loop(2, "again", reply, 255, &rlen), 0);
    CHECK_EQ(execMasterNextSeq(master, 2), 1);
}

/* A blocking execMasterTransact in another thread waits until the
 * Begin/Step transaction in flight is over, then runs (seq after it). */
typedef struct tx_arg { int rc; byte reply[255]; word rlen; } tx_arg;

static void *transact_thread(void *arg)
{
    tx_arg *a = arg;
    a->rc = transact_str(1, "thread", a->reply, &a->rlen);
    return NULL;
}

static void test_transact_waits_for_step(void)
{
    unsigned before = load(&slaves[0].applied);
    int64_t deadline;
    REQUIRE_ZERO(execMasterBegin(master, 1, (const byte *)"loop", 4, &deadline));
    tx_arg a = {.rc = -1};
    pthread_t t;
    pthread_create(&t, NULL, transact_thread, &a);
    struct pollfd p = {.fd = fap_port_fd(execMasterPort(master)), .events = POLLIN};
    byte reply[255];
    word rlen = 0;
    int rc;
    do {
        int64_t left = deadline - now_ns();
        poll(&p, 1, left > 0 ? (int)((left + 999999) / 1000000) : 0);
        rc = execMasterStep(master, reply, 255, &rlen, &deadline);
    } while (rc == EXEC_MASTER_MORE);
    CHECK_EQ(rc, 0);
    CHECK_EQ(reply[1], before + 1);           /* ours went first */
    CHECK_MEM(reply + 2, "loop", 4);
    pthread_join(t, NULL);
    CHECK_EQ(a.rc, 0);
    CHECK_EQ(a.reply[1], before + 2);
    CHECK_MEM(a.reply + 2, "thread", 6);
}

int main(void)
{
    int err = setup();
    if (err) {
        fprintf(stderr, "setup failed: %d\n", err);
        printf("0 passed, 1 failed\n");
        return 1;
    }
    static const unit_test tests[] = {
        UNIT(test_poll_each_slave),
        UNIT(test_dropped_reply_applied_once),
        UNIT(test_retried_seq_zero_processed_again),
        UNIT(test_corrupt_reply_caught_by_crc),
        UNIT(test_corrupt_request_ignored),
        UNIT(test_broadcast_reaches_all_nobody_answers),
        UNIT(test_message_during_reply_not_answered),
        UNIT(test_broadcast_during_reply_processed),
        UNIT(test_absent_node_times_out),
        UNIT(test_bad_arguments),
        UNIT(test_step_transaction),
        UNIT(test_step_busy_and_abort),
        UNIT(test_step_retry_after_dropped_reply),
        UNIT(test_step_timeout_seq_zero),
        UNIT(test_transact_waits_for_step),
        UNIT(test_turnaround_delay),
        UNIT(test_stop_wakes_serve),
        UNIT(test_port_vanishes),
        UNIT(test_teardown),
    };
    return unit_run(tests, sizeof tests / sizeof tests[0]);
}
