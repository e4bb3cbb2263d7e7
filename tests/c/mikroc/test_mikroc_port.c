/* mikroC nodes on real pty ports (virtual bus, one thread): bytes on the
 * wire, read-ahead kept across Polls, stale input, open/close, a port that
 * vanishes. */
#include <errno.h>
#include <poll.h>
#include <pthread.h>

#include "fap_vbus.h"
#include "mikroc_rs485.h"
#include "unit.h"

#define WAIT_MS 5000

static fap_vbus *bus;

static fap_port_options pty_options(void)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.baud = 115200;
    o.rs485_mode = FAP_RS485_NONE;
    return o;
}

static int read_exact(fap_port *p, uint8_t *buf, size_t n)
{
    int64_t dl = fap_port_now_ns() + (int64_t)WAIT_MS * 1000000;
    size_t got = 0;
    while (got < n) {
        ssize_t r = fap_port_read(p, buf + got, n - got, dl);
        if (r <= 0)
            return -1;
        got += (size_t)r;
    }
    return 0;
}

/* What Send puts on the wire is the codec's frame, byte for byte. */
static void test_send_bytes_on_the_wire(void)
{
    fap_port_options o = pty_options();
    mikrocRS485_ctx m, s;
    mikrocRS485_CtxInitMaster(&m);
    mikrocRS485_CtxInitSlave(&s, 169);
    int r = mikrocRS485_CtxOpen(&m, fap_vbus_port_path(bus, 0), 0, &o);
    REQUIRE(r == 0);
    fap_port *probe = NULL;
    r = fap_port_open(&probe, fap_vbus_port_path(bus, 1), &o);
    REQUIRE(r == 0);
    mikrocRS485_CtxBind(&s, probe);     /* slave sends through the probe port */

    static const char *payloads[] = {"", "\x96", "\xA9\x96", "\x00\xA9\xFF"};
    for (unsigned len = 0; len <= 3; len++) {
        uint8_t want[8], got[8];
        int n = mikrocRS485_Encode(want, (const uint8_t *)payloads[len], len, 0x96, 1);
        CHECK_EQ(mikrocRS485_CtxSend(&m, payloads[len], len, 0x96), 0);
        CHECK_EQ(read_exact(probe, got, (size_t)n), 0);
        CHECK_MEM(got, want, (size_t)n);
    }
    /* a slave sends from its own address; the argument is ignored */
    uint8_t want[8];
    int n = mikrocRS485_Encode(want, (const uint8_t *)"\x00", 1, 169, 0);
    CHECK_EQ(n, 6);
    CHECK_MEM(want, "\x96\xA8\x41\x00\x16\xA9", 6);   /* vector "slave 169" */
    CHECK_EQ(mikrocRS485_CtxSend(&s, "\x00", 1, 7), 0);
    char mbuf[7] = {0};
    CHECK_EQ(mikrocRS485_CtxPoll(&m, mbuf, WAIT_MS), MIKROC_RS485_POLL_READY);
    CHECK_EQ((uint8_t)mbuf[6], 169);
    /* datalen > 3: rejected, nothing written */
    CHECK_EQ(mikrocRS485_CtxSend(&m, "\x01\x02\x03\x04", 4, 1), -EINVAL);
    mikrocRS485_stats st;
    mikrocRS485_CtxGetStats(&m, &st);
    CHECK_EQ(st.last_send_error, -EINVAL);
    uint8_t b;
    CHECK_EQ(fap_port_read(probe, &b, 1, 0), 0);
    /* double open refused; close is idempotent */
    CHECK_EQ(mikrocRS485_CtxOpen(&m, fap_vbus_port_path(bus, 0), 0, &o), -EBUSY);
    mikrocRS485_CtxClose(&m);
    mikrocRS485_CtxClose(&m);
    CHECK_EQ(mikrocRS485_CtxSend(&m, "", 0, 1), -ENOTCONN);
    fap_port_close(probe);
}

/* Poll stops at the end of the frame that raised a flag; the bytes read
 * ahead stay for the next call. With a flag already set it reads nothing. */
static void test_poll_keeps_read_ahead(void)
{
    fap_port_options o = pty_options();
    mikrocRS485_ctx m, s;
    mikrocRS485_CtxInitMaster(&m);
    mikrocRS485_CtxInitSlave(&s, 7);
    int r = mikrocRS485_CtxOpen(&m, fap_vbus_port_path(bus, 0), 0, &o);
    REQUIRE(r == 0);
    r = mikrocRS485_CtxOpen(&s, fap_vbus_port_path(bus, 1), 0, &o);
    REQUIRE(r == 0);
    /* three requests in one go */
    uint8_t burst[24];
    size_t n = 0;
    for (int i = 1; i <= 3; i++)
        n += (size_t)mikrocRS485_Encode(burst + n, (const uint8_t *)&(uint8_t){(uint8_t)i}, 1, 7, 1);
    CHECK_EQ(fap_port_write(m.port, burst, n), (ssize_t)n);
    char buf[6] = {0};
    for (int i = 1; i <= 3; i++) {
        CHECK_EQ(mikrocRS485_CtxPoll(&s, buf, WAIT_MS), MIKROC_RS485_POLL_READY);
        CHECK_EQ(buf[0], i);
        /* flag still set: returns at once, nothing consumed */
        CHECK_EQ(mikrocRS485_CtxPoll(&s, buf, WAIT_MS), MIKROC_RS485_POLL_READY);
        buf[4] = 0;
    }
    CHECK_EQ(mikrocRS485_CtxPoll(&s, buf, 0), 0);
    mikrocRS485_stats st;
    mikrocRS485_CtxGetStats(&s, &st);
    CHECK_EQ(st.frames, 3);
    CHECK_EQ(st.overruns, 0);
    mikrocRS485_CtxClose(&m);
    mikrocRS485_CtxClose(&s);
}

/* ResetRx forgets half a frame and input not read yet. */
static void test_reset_rx_drops_stale_input(void)
{
    fap_port_options o = pty_options();
    mikrocRS485_ctx m, s;
    mikrocRS485_CtxInitMaster(&m);
    mikrocRS485_CtxInitSlave(&s, 9);
    int r = mikrocRS485_CtxOpen(&m, fap_vbus_port_path(bus, 0), 0, &o);
    REQUIRE(r == 0);
    r = mikrocRS485_CtxOpen(&s, fap_vbus_port_path(bus, 1), 0, &o);
    REQUIRE(r == 0);
    uint8_t fr[8];
    mikrocRS485_Encode(fr, (const uint8_t *)"\x55", 1, 9, 0);
    char mbuf[7] = {0};
    for (int i = 0; i < 3; i++)          /* half a reply in the decoder */
        mikrocRS485_CtxReceiveByte(&m, mbuf, fr[i]);
    CHECK_EQ(mikrocRS485_CtxSend(&s, "\x66", 1, 0), 0);   /* a stale reply */
    /* its start byte has arrived (whatever is still in flight after the
     * reset is a tail without start byte: noise) */
    struct pollfd pf = {.fd = fap_port_fd(m.port), .events = POLLIN};
    CHECK_EQ(poll(&pf, 1, WAIT_MS), 1);
    CHECK_EQ(mikrocRS485_CtxResetRx(&m), 0);
    CHECK_EQ(mikrocRS485_CtxSend(&s, "\x88", 1, 0), 0);
    CHECK_EQ(mikrocRS485_CtxPoll(&m, mbuf, WAIT_MS), MIKROC_RS485_POLL_READY);
    CHECK_EQ((uint8_t)mbuf[0], 0x88);
    mikrocRS485_stats st;
    mikrocRS485_CtxGetStats(&m, &st);
    CHECK_EQ(st.errors, 0);             /* no abort of the forgotten half */
    CHECK_EQ(st.frames, 1);             /* the stale 0x66 never delivered */
    mikrocRS485_CtxClose(&m);
    mikrocRS485_CtxClose(&s);
}

/* The vendor routines through mikrocRS485_Open (the host's UARTx_Init). */
static void test_global_open_close(void)
{
    fap_port_options o = pty_options();
    CHECK(mikrocRS485_Open("/nonexistent/tty", 9600, &o) < 0);
    int r = mikrocRS485_Open(fap_vbus_port_path(bus, 0), 9600, &o);
    REQUIRE(r == 0);
    CHECK_EQ(mikrocRS485_Open(fap_vbus_port_path(bus, 0), 9600, &o), -EBUSY);
    RS485Slave_Init(3);                 /* Init after Open keeps the port */
    mikrocRS485_ctx m;
    mikrocRS485_CtxInitMaster(&m);
    r = mikrocRS485_CtxOpen(&m, fap_vbus_port_path(bus, 1), 0, &o);
    REQUIRE(r == 0);
    CHECK_EQ(mikrocRS485_CtxSend(&m, "\x42", 1, 3), 0);
    char sbuf[6] = {0};
    CHECK_EQ(mikrocRS485_Poll(sbuf, 0, WAIT_MS), MIKROC_RS485_POLL_READY);
    CHECK_EQ(sbuf[0], 0x42);
    RS485Slave_Send(sbuf, 1);
    CHECK_EQ(mikrocRS485_LastSendError(0), 0);
    char mbuf[7] = {0};
    CHECK_EQ(mikrocRS485_CtxPoll(&m, mbuf, WAIT_MS), MIKROC_RS485_POLL_READY);
    CHECK_EQ(mbuf[6], 3);
    mikrocRS485_Close();
    mikrocRS485_Close();
    RS485Slave_Send(sbuf, 1);
    CHECK_EQ(mikrocRS485_LastSendError(0), -ENOTCONN);
    mikrocRS485_CtxClose(&m);
}

/* The device goes away under a waiting Poll: an error, not a hang. */
static void test_port_vanishes(void)
{
    fap_port_options o = pty_options();
    mikrocRS485_ctx s;
    mikrocRS485_CtxInitSlave(&s, 1);
    int r = mikrocRS485_CtxOpen(&s, fap_vbus_port_path(bus, 1), 0, &o);
    REQUIRE(r == 0);
    CHECK_EQ(fap_vbus_disconnect(bus, 1, 300), 0);
    char buf[6] = {0};
    r = mikrocRS485_CtxPoll(&s, buf, WAIT_MS);
    CHECK(r < 0);
    if (r >= 0)
        fprintf(stderr, "  poll returned %d\n", r);
    mikrocRS485_stats st;
    mikrocRS485_CtxGetStats(&s, &st);
    CHECK_EQ(st.last_rx_error, r);
    mikrocRS485_CtxClose(&s);
}

/* Documented: one thread receives on a context while another sends on it
 * (tsan checks the claim). Slave 5 answers each request with its byte. */
typedef struct poller {
    mikrocRS485_ctx *m;
    int got[8];
    int n;
} poller;

static void *poll_replies(void *arg)
{
    poller *p = arg;
    char buf[7] = {0};
    while (p->n < 8) {
        int r = mikrocRS485_CtxPoll(p->m, buf, WAIT_MS);
        if (r <= 0)
            break;
        if (r & MIKROC_RS485_POLL_READY)
            p->got[p->n++] = buf[0];
        buf[4] = buf[5] = 0;
    }
    return NULL;
}

static void test_send_beside_a_receiving_thread(void)
{
    fap_port_options o = pty_options();
    mikrocRS485_ctx m, s;
    mikrocRS485_CtxInitMaster(&m);
    mikrocRS485_CtxInitSlave(&s, 5);
    int r = mikrocRS485_CtxOpen(&m, fap_vbus_port_path(bus, 0), 0, &o);
    REQUIRE(r == 0);
    r = mikrocRS485_CtxOpen(&s, fap_vbus_port_path(bus, 1), 0, &o);
    REQUIRE(r == 0);
    poller p = {.m = &m};
    pthread_t t;
    r = pthread_create(&t, NULL, poll_replies, &p);
    REQUIRE(r == 0);
    char sbuf[6] = {0};
    for (int i = 0; i < 8; i++) {
        char b = (char)(i + 1);
        CHECK_EQ(mikrocRS485_CtxSend(&m, &b, 1, 5), 0);    /* main thread sends */
        CHECK_EQ(mikrocRS485_CtxPoll(&s, sbuf, WAIT_MS), MIKROC_RS485_POLL_READY);
        sbuf[4] = 0;
        CHECK_EQ(mikrocRS485_CtxSend(&s, sbuf, 1, 0), 0);  /* echo it back */
    }
    pthread_join(t, NULL);
    CHECK_EQ(p.n, 8);
    for (int i = 0; i < p.n; i++)
        CHECK_EQ(p.got[i], i + 1);
    mikrocRS485_CtxClose(&m);
    mikrocRS485_CtxClose(&s);
}

int main(void)
{
    fap_vbus_options vo;
    fap_vbus_options_init(&vo);
    vo.n_ports = 2;
    int r = fap_vbus_open(&bus, &vo);
    if (r < 0) {
        fprintf(stderr, "fap_vbus_open: %d\n", r);
        printf("0 passed, 1 failed\n");
        return 1;
    }
    static const unit_test tests[] = {
        UNIT(test_send_bytes_on_the_wire),
        UNIT(test_poll_keeps_read_ahead),
        UNIT(test_reset_rx_drops_stale_input),
        UNIT(test_global_open_close),
        UNIT(test_send_beside_a_receiving_thread),
        UNIT(test_port_vanishes),
    };
    int rc = unit_run(tests, sizeof tests / sizeof tests[0]);
    fap_vbus_close(bus);
    return rc;
}
