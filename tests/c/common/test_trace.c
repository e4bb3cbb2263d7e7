/* Wire trace hooks (fap_trace.h) of the three protocol handles on the
 * virtual bus: every frame seen with its exact bytes, bad ones flagged.
 * A raw port injects good and damaged frames; the hooks must report each
 * one, in order, with the right direction and status. */
#include <errno.h>
#include <pthread.h>
#include <string.h>
#include <time.h>

#include "unit.h"
#include "exec_async_engine.h"
#include "fap_port.h"
#include "fap_trace.h"
#include "fap_vbus.h"
#include "fapx.h"
#include "mikroc_rs485.h"
#include "fap/codec.h"

#define MAX_REC 64

typedef struct rec_frame {
    int dir, status;
    int64_t t_ns;
    uint8_t data[1100];
    size_t len;
} rec_frame;

typedef struct recorder {
    pthread_mutex_t mu;
    pthread_cond_t cv;
    rec_frame f[MAX_REC];
    int n;
} recorder;

static void rec_init(recorder *r)
{
    memset(r, 0, sizeof *r);
    pthread_mutex_init(&r->mu, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&r->cv, &ca);
    pthread_condattr_destroy(&ca);
}

static void rec_destroy(recorder *r)
{
    pthread_mutex_destroy(&r->mu);
    pthread_cond_destroy(&r->cv);
}

static void on_trace(void *ctx, const fap_trace_frame *f)
{
    recorder *r = ctx;
    pthread_mutex_lock(&r->mu);
    if (r->n < MAX_REC) {
        rec_frame *d = &r->f[r->n++];
        d->dir = f->dir;
        d->status = f->status;
        d->t_ns = f->t_ns;
        d->len = f->len < sizeof d->data ? f->len : sizeof d->data;
        memcpy(d->data, f->data, d->len);
    }
    pthread_cond_broadcast(&r->cv);
    pthread_mutex_unlock(&r->mu);
}

/* Wait until at least n frames were recorded (5 s at most). */
static int rec_wait(recorder *r, int n)
{
    struct timespec until;
    clock_gettime(CLOCK_MONOTONIC, &until);
    until.tv_sec += 5;
    pthread_mutex_lock(&r->mu);
    while (r->n < n) {
        if (pthread_cond_timedwait(&r->cv, &r->mu, &until) == ETIMEDOUT)
            break;
    }
    int got = r->n;
    pthread_mutex_unlock(&r->mu);
    return got;
}

/* Index of the first frame from `from` with this direction, or -1. */
static int rec_find(recorder *r, int from, int dir)
{
    pthread_mutex_lock(&r->mu);
    int found = -1;
    for (int i = from; i < r->n && found < 0; i++)
        if (r->f[i].dir == dir)
            found = i;
    pthread_mutex_unlock(&r->mu);
    return found;
}

static fap_vbus *bus;
static fap_port *raw;

static fap_port_options none_opts(void)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = FAP_RS485_NONE;
    return o;
}

static int open_bus(unsigned ports)
{
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    bo.n_ports = ports;
    if (fap_vbus_open(&bus, &bo))
        return -1;
    fap_port_options po = none_opts();
    return fap_port_open(&raw, fap_vbus_port_path(bus, 0), &po);
}

static void close_bus(void)
{
    fap_port_close(raw);
    fap_vbus_close(bus);
}

/* ---- FAP ---- */

static void test_fapx_trace(void)
{
    REQUIRE(open_bus(2) == 0);
    recorder r;
    rec_init(&r);
    fapx_options o;
    fapx_options_init(&o);
    o.mode = FAPX_SLAVE;
    o.id = 3;
    o.port = none_opts();
    fapx *h = NULL;
    REQUIRE(fapx_open(&h, fap_vbus_port_path(bus, 1), &o) == 0);
    fapx_set_trace(h, on_trace, &r);

    /* 1: a good QUERY_ID for slave 3: rx ok, then the slave's ID answer (tx) */
    uint8_t q[LF_FAP_MAX_FRAME];
    size_t qn = lf_fap_encode(q, sizeof q, LF_FAP_QUERY_ID, 3, 0, NULL, 0);
    REQUIRE(fap_port_write(raw, q, qn) == (ssize_t)qn);
    CHECK(rec_wait(&r, 2) >= 2);
    CHECK_EQ(r.f[0].dir, FAP_TRACE_RX);
    CHECK_EQ(r.f[0].status, FAP_TRACE_OK);
    CHECK_EQ(r.f[0].len, qn);
    CHECK_MEM(r.f[0].data, q, qn);
    CHECK(r.f[0].t_ns > 0 && r.f[0].t_ns <= fap_port_now_ns());
    int tx = rec_find(&r, 1, FAP_TRACE_TX);
    REQUIRE(tx >= 0);
    uint8_t id[LF_FAP_MAX_FRAME];
    size_t idn = lf_fap_encode(id, sizeof id, LF_FAP_ID, 0, 3, NULL, 0);
    CHECK_EQ(r.f[tx].status, FAP_TRACE_OK);
    CHECK_EQ(r.f[tx].len, idn);
    CHECK_MEM(r.f[tx].data, id, idn);
    CHECK(r.f[tx].t_ns >= r.f[0].t_ns);

    /* 2: a DATA frame with a wrong CRC: reported whole, BAD_CRC */
    int base = rec_wait(&r, 2);
    uint8_t d[LF_FAP_MAX_FRAME];
    size_t dn = lf_fap_encode(d, sizeof d, LF_FAP_DATA, 3, 0, (const uint8_t *)"hello", 5);
    d[dn - 1] ^= 0x5A;
    REQUIRE(fap_port_write(raw, d, dn) == (ssize_t)dn);
    CHECK(rec_wait(&r, base + 1) >= base + 1);
    CHECK_EQ(r.f[base].dir, FAP_TRACE_RX);
    CHECK_EQ(r.f[base].status, FAP_TRACE_BAD_CRC);
    CHECK_EQ(r.f[base].len, dn);
    CHECK_MEM(r.f[base].data, d, dn);

    /* 3: a bad size field after a full marker: BAD_FRAME, the header bytes */
    base = r.n;
    uint8_t bad[12];
    memcpy(bad, q, 12);
    bad[8] = 2;            /* size 2 < 13 */
    bad[9] = 0;
    REQUIRE(fap_port_write(raw, bad, sizeof bad) == (ssize_t)sizeof bad);
    CHECK(rec_wait(&r, base + 1) >= base + 1);
    CHECK_EQ(r.f[base].status, FAP_TRACE_BAD_FRAME);
    CHECK_EQ(r.f[base].len, 10);
    CHECK_MEM(r.f[base].data, bad, 10);

    /* 4: half a frame, then silence: TRUNCATED after the inter-byte gap */
    base = r.n;
    dn = lf_fap_encode(d, sizeof d, LF_FAP_DATA, 3, 0, (const uint8_t *)"hello", 5);
    REQUIRE(fap_port_write(raw, d, 14) == 14);
    CHECK(rec_wait(&r, base + 1) >= base + 1);
    CHECK_EQ(r.f[base].status, FAP_TRACE_TRUNCATED);
    CHECK_EQ(r.f[base].len, 14);
    CHECK_MEM(r.f[base].data, d, 14);

    /* the hook off: nothing more is recorded */
    fapx_set_trace(h, NULL, NULL);
    base = r.n;
    REQUIRE(fap_port_write(raw, q, qn) == (ssize_t)qn);
    fapx_stats st;
    for (int i = 0; i < 500; i++) {       /* until the engine counted the frame */
        fapx_get_stats(h, &st);
        if (st.frames_rx >= 2)
            break;
        struct timespec ts = {0, 2000000};
        nanosleep(&ts, NULL);
    }
    CHECK_EQ(r.n, base);
    fapx_close(h);
    rec_destroy(&r);
    close_bus();
}

/* ---- exec async ---- */

static int echo_handler(void *ctx, const execSlaveRequest *req, byte *reply, word cap)
{
    (void)ctx;
    word n = req->len < cap ? req->len : cap;
    memcpy(reply, req->data, n);
    return n;
}

static void *serve(void *arg)
{
    execSlave *s = arg;
    while (execSlaveServe(s, 1000) != -ECANCELED) {
    }
    return NULL;
}

static void test_exec_trace(void)
{
    REQUIRE(open_bus(3) == 0);
    recorder rm, rs;
    rec_init(&rm);
    rec_init(&rs);
    fap_port_options po = none_opts();
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    so.node = 5;
    execSlave *s = NULL;
    REQUIRE(execSlaveOpen(&s, fap_vbus_port_path(bus, 2), &po, &so, echo_handler, NULL) == 0);
    execSlaveSetTrace(s, on_trace, &rs);
    pthread_t th;
    pthread_create(&th, NULL, serve, s);
    execMasterOptions mo;
    execMasterOptionsInit(&mo);
    mo.reply_timeout_us = 1000000;
    execMaster *m = NULL;
    REQUIRE(execMasterOpen(&m, fap_vbus_port_path(bus, 1), &po, &mo) == 0);
    execMasterSetTrace(m, on_trace, &rm);

    /* a transaction: master tx request, rx reply; slave rx request, tx reply */
    byte req[] = {0x10, 0x02, 0x41};       /* DLEs in the data: stuffed on the wire */
    byte wire[EXEC_ASYNC_MAX_FRAME], wire_reply[EXEC_ASYNC_MAX_FRAME];
    word wn = execAsyncBufferOut(5, req, wire, sizeof req, 0);
    word rn = execAsyncBufferOut(5, req, wire_reply, sizeof req, 0);
    byte reply[255];
    word rlen = 0;
    REQUIRE(execMasterTransact(m, 5, req, sizeof req, reply, sizeof reply, &rlen) == 0);
    CHECK(rec_wait(&rm, 2) == 2);
    CHECK_EQ(rm.f[0].dir, FAP_TRACE_TX);
    CHECK_EQ(rm.f[0].len, wn);
    CHECK_MEM(rm.f[0].data, wire, wn);
    CHECK_EQ(rm.f[1].dir, FAP_TRACE_RX);
    CHECK_EQ(rm.f[1].status, FAP_TRACE_OK);
    CHECK_EQ(rm.f[1].len, rn);
    CHECK_MEM(rm.f[1].data, wire_reply, rn);
    CHECK(rec_wait(&rs, 2) >= 2);
    CHECK_EQ(rs.f[0].dir, FAP_TRACE_RX);
    CHECK_EQ(rs.f[0].status, FAP_TRACE_OK);
    CHECK_MEM(rs.f[0].data, wire, wn);
    CHECK_EQ(rs.f[1].dir, FAP_TRACE_TX);
    CHECK_MEM(rs.f[1].data, wire_reply, rn);

    /* injected on the raw port: a bad CRC, then a frame cut short by the
     * next DLE STX (FRAMING), then a good frame for another node */
    int base = rs.n;
    byte bad[EXEC_ASYNC_MAX_FRAME];
    word bn = execAsyncBufferOut(5, req, bad, sizeof req, 1);
    bad[bn - 1] ^= 0xFF;
    REQUIRE(fap_port_write(raw, bad, bn) == (ssize_t)bn);
    CHECK(rec_wait(&rs, base + 1) >= base + 1);
    CHECK_EQ(rs.f[base].status, FAP_TRACE_BAD_CRC);
    CHECK_EQ(rs.f[base].len, bn);
    CHECK_MEM(rs.f[base].data, bad, bn);

    base = rs.n;
    byte cut[64], other[EXEC_ASYNC_MAX_FRAME];
    word on = execAsyncBufferOut(9, (byte *)"xy", other, 2, 0);
    memcpy(cut, wire, 6);                  /* DLE STX node seq and 2 data bytes */
    memcpy(cut + 6, other, on);
    REQUIRE(fap_port_write(raw, cut, 6 + on) == (ssize_t)(6 + on));
    CHECK(rec_wait(&rs, base + 2) >= base + 2);
    CHECK_EQ(rs.f[base].status, FAP_TRACE_BAD_FRAME);
    CHECK_EQ(rs.f[base].len, 6);
    CHECK_MEM(rs.f[base].data, cut, 6);
    CHECK_EQ(rs.f[base + 1].status, FAP_TRACE_OK);   /* heard, though not for node 5 */
    CHECK_EQ(rs.f[base + 1].len, on);
    CHECK_MEM(rs.f[base + 1].data, other, on);

    execSlaveStop(s);
    pthread_join(th, NULL);
    execSlaveClose(s);
    execMasterClose(m);
    rec_destroy(&rm);
    rec_destroy(&rs);
    close_bus();
}

/* ---- mikroC ---- */

static void test_mikroc_trace(void)
{
    REQUIRE(open_bus(2) == 0);
    recorder r;
    rec_init(&r);
    mikrocRS485_ctx c;
    mikrocRS485_CtxInitMaster(&c);
    fap_port_options po = none_opts();
    REQUIRE(mikrocRS485_CtxOpen(&c, fap_vbus_port_path(bus, 1), 0, &po) == 0);
    mikrocRS485_CtxSetTrace(&c, on_trace, &r);

    /* tx: the frame as encoded */
    uint8_t f[MIKROC_RS485_FRAME_MAX];
    int fn = mikrocRS485_Encode(f, (const uint8_t *)"\x01\x96\x03", 3, 7, 1);
    REQUIRE(fn > 0);
    REQUIRE(mikrocRS485_CtxSend(&c, "\x01\x96\x03", 3, 7) == 0);
    CHECK_EQ(r.n, 1);
    CHECK_EQ(r.f[0].dir, FAP_TRACE_TX);
    CHECK_EQ(r.f[0].status, FAP_TRACE_OK);
    CHECK_EQ(r.f[0].len, fn);
    CHECK_MEM(r.f[0].data, f, (size_t)fn);
    uint8_t junk[16];
    while (fap_port_read(raw, junk, sizeof junk, fap_port_now_ns() + 50000000) > 0) {
    }

    /* rx: a good reply, a bad checksum, a frame cut off by a new start */
    uint8_t in[3][MIKROC_RS485_FRAME_MAX];
    int n0 = mikrocRS485_Encode(in[0], (const uint8_t *)"ok", 2, 7, 0);
    int n1 = mikrocRS485_Encode(in[1], (const uint8_t *)"no", 2, 7, 0);
    in[1][n1 - 2] ^= 0x01;                 /* the checksum byte before the stop */
    int n2 = mikrocRS485_Encode(in[2], (const uint8_t *)"x", 1, 7, 0);
    REQUIRE(n2 > 3);
    uint8_t stream[32];
    size_t sn = 0;
    memcpy(stream + sn, in[0], (size_t)n0); sn += (size_t)n0;
    memcpy(stream + sn, in[1], (size_t)n1); sn += (size_t)n1;
    memcpy(stream + sn, in[2], 3);          sn += 3;   /* start, address, datalen */
    memcpy(stream + sn, in[0], (size_t)n0); sn += (size_t)n0;
    REQUIRE(fap_port_write(raw, stream, sn) == (ssize_t)sn);
    char buf[7];
    for (int i = 0; i < 20 && r.n < 5; i++) {
        memset(buf, 0, sizeof buf);
        (void)mikrocRS485_CtxPoll(&c, buf, 200);
    }
    REQUIRE(r.n == 5);
    CHECK_EQ(r.f[1].dir, FAP_TRACE_RX);
    CHECK_EQ(r.f[1].status, FAP_TRACE_OK);
    CHECK_EQ(r.f[1].len, n0);
    CHECK_MEM(r.f[1].data, in[0], (size_t)n0);
    CHECK_EQ(r.f[2].status, FAP_TRACE_BAD_CRC);
    CHECK_EQ(r.f[2].len, n1);
    CHECK_MEM(r.f[2].data, in[1], (size_t)n1);
    CHECK_EQ(r.f[3].status, FAP_TRACE_TRUNCATED);
    CHECK_EQ(r.f[3].len, 3);
    CHECK_MEM(r.f[3].data, in[2], 3);
    CHECK_EQ(r.f[4].status, FAP_TRACE_OK);
    CHECK_MEM(r.f[4].data, in[0], (size_t)n0);

    mikrocRS485_CtxClose(&c);
    rec_destroy(&r);
    close_bus();
}

static void test_status_names(void)
{
    CHECK(strcmp(fap_trace_status_name(FAP_TRACE_OK), "ok") == 0);
    CHECK(strcmp(fap_trace_status_name(FAP_TRACE_BAD_CRC), "bad_crc") == 0);
    CHECK(strcmp(fap_trace_status_name(FAP_TRACE_TRUNCATED), "truncated") == 0);
    CHECK(strcmp(fap_trace_status_name(99), "?") == 0);
}

UNIT_MAIN(UNIT(test_status_names), UNIT(test_fapx_trace), UNIT(test_exec_trace),
          UNIT(test_mikroc_trace))
