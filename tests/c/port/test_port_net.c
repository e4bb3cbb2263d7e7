/* The network transports of the port layer (port_url.c, port_telnet.c,
 * port_net.c): URL parsing, the Telnet codec on literal byte vectors, and
 * fap_port_open("tcp://...") / ("rfc2217://...") against small servers on
 * 127.0.0.1 run by this test: a raw echo server and a scripted RFC 2217
 * server (answers, refuses or ignores options). Every byte value both
 * ways, a dropped connection read as a vanished device and reopened, the
 * documented error codes. */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <sys/socket.h>
#include <unistd.h>

#include "fap_port.h"
#include "port/port_net.h"
#include "port/port_telnet.h"
#include "port/port_url.h"
#include "unit.h"

#define WAIT_NS (10 * LF_NS_PER_S)

/* ---- URL parsing --------------------------------------------------------- */

static void test_url_parse(void)
{
    lf_port_url u;
    /* a refused string still says what it is: the one parse classifies */
    CHECK_EQ(lf_port_url_parse("/dev/ttyUSB0", &u), FAP_PORT_EURL);
    CHECK_EQ(u.scheme, LF_PORT_DEVICE);
    CHECK_EQ(lf_port_url_parse("socket://h:1", &u), FAP_PORT_EURL);
    CHECK_EQ(u.scheme, LF_PORT_OTHER);
    CHECK_EQ(lf_port_url_parse(NULL, &u), FAP_PORT_EURL);
    CHECK_EQ(u.scheme, LF_PORT_OTHER);
    CHECK_EQ(lf_port_url_parse("tcp://h", &u), FAP_PORT_EURL);
    CHECK_EQ(u.scheme, LF_PORT_TCP);
    CHECK_EQ(lf_port_url_parse("rfc2217://h:1", &u), 0);
    CHECK_EQ(u.scheme, LF_PORT_RFC2217);
    CHECK_EQ(lf_port_url_parse("tcp://192.0.2.7:4001", &u), 0);
    CHECK_EQ(u.scheme, LF_PORT_TCP);
    CHECK(strcmp(u.host, "192.0.2.7") == 0 && strcmp(u.port, "4001") == 0);
    CHECK_EQ(u.connect_ms, LF_URL_CONNECT_MS_DEFAULT);
    CHECK_EQ(u.rtt_ms, LF_URL_RTT_MS_DEFAULT);
    CHECK_EQ(u.option_ms, LF_URL_OPTION_MS_DEFAULT);
    CHECK_EQ(lf_port_url_parse("rfc2217://[::1]:65535?rtt_ms=5&connect_ms=100&option_ms=0", &u), 0);
    CHECK(strcmp(u.host, "::1") == 0 && strcmp(u.port, "65535") == 0);
    CHECK_EQ(u.rtt_ms, 5);
    CHECK_EQ(u.connect_ms, 100);
    CHECK_EQ(u.option_ms, 0);
    CHECK_EQ(lf_port_url_parse("tcp://pi.local:2000", &u), 0);
    const char *bad[] = {
        "tcp://", "tcp://host", "tcp://host:", "tcp://host:99999", "tcp://host:0",
        "tcp://:80", "foo://host:1", "tcp://host:1?", "tcp://host:1?x=1", "tcp://host:1?rtt_ms",
        "tcp://host:1?rtt_ms=", "tcp://host:1?rtt_ms=-1", "tcp://host:1?rtt_ms=600001",
        "tcp://host:1?rtt_ms=1&", "tcp://h:0000000000080", "rfc2217://[::1", "rfc2217://[::1]80",
        "tcp://h/x:1", "tcp://host:1a", "/dev/ttyS0", "",
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        int r = lf_port_url_parse(bad[i], &u);
        if (r != FAP_PORT_EURL)
            fprintf(stderr, "accepted: %s\n", bad[i]);
        CHECK_EQ(r, FAP_PORT_EURL);
    }
    char longhost[400] = "tcp://";
    memset(longhost + 6, 'a', 300);
    strcpy(longhost + 306, ":80");
    CHECK_EQ(lf_port_url_parse(longhost, &u), FAP_PORT_EURL);
}

/* ---- Telnet codec on literal vectors -------------------------------------- */

typedef struct cmds {
    int n;
    uint8_t verb[8], opt[8];
    uint8_t sb[8][LF_TN_SB_MAX];
    size_t sblen[8];
} cmds;

static void record(void *ctx, uint8_t verb, uint8_t opt, const uint8_t *sb, size_t len)
{
    cmds *c = ctx;
    if (c->n >= 8)
        return;
    c->verb[c->n] = verb;
    c->opt[c->n] = opt;
    if (sb && len)
        memcpy(c->sb[c->n], sb, len);
    c->sblen[c->n] = len;
    c->n++;
}

static void test_telnet_codec(void)
{
    /* data FF doubled, CR NUL and CR LF untouched */
    const uint8_t data[] = {0x01, 0xFF, 0x0D, 0x00, 0x0D, 0x0A, 0xFF};
    uint8_t enc[16];
    size_t n = lf_telnet_escape(data, sizeof data, enc);
    const uint8_t want[] = {0x01, 0xFF, 0xFF, 0x0D, 0x00, 0x0D, 0x0A, 0xFF, 0xFF};
    CHECK_EQ(n, sizeof want);
    CHECK_MEM(enc, want, sizeof want);

    /* a stream of data, a DO, an SB with an escaped FF, split at every byte */
    const uint8_t stream[] = {'a', 0xFF, 0xFF, 0xFF, LF_TN_DO, 44, 'b',
                              0xFF, LF_TN_SB, 44, 101, 0x00, 0x01, 0xFF, 0xFF, 0x00,
                              0xFF, LF_TN_SE, 'c', 0xFF, 241 /* NOP */, 0x0D, 0x00};
    for (size_t split = 1; split <= sizeof stream; split++) {
        lf_telnet t;
        lf_telnet_init(&t);
        cmds c = {0};
        uint8_t out[64];
        size_t o = 0;
        for (size_t i = 0; i < sizeof stream; i += split) {
            size_t k = sizeof stream - i < split ? sizeof stream - i : split;
            o += lf_telnet_rx(&t, stream + i, k, out + o, record, &c);
        }
        const uint8_t plain[] = {'a', 0xFF, 'b', 'c', 0x0D, 0x00};
        CHECK_EQ(o, sizeof plain);
        CHECK_MEM(out, plain, sizeof plain);
        CHECK_EQ(c.n, 2);
        CHECK_EQ(c.verb[0], LF_TN_DO);
        CHECK_EQ(c.opt[0], 44);
        CHECK_EQ(c.verb[1], LF_TN_SB);
        CHECK_EQ(c.opt[1], 44);
        const uint8_t sb[] = {101, 0x00, 0x01, 0xFF, 0x00};
        CHECK_EQ(c.sblen[1], sizeof sb);
        CHECK_MEM(c.sb[1], sb, sizeof sb);
    }

    /* SET-BAUDRATE 115200 = 00 01 C2 00; a value with FF is escaped */
    uint8_t msg[16];
    const uint8_t baud[] = {0x00, 0x01, 0xC2, 0x00};
    n = lf_telnet_cpc(LF_CPC_SET_BAUDRATE, baud, 4, msg);
    const uint8_t m1[] = {0xFF, 0xFA, 44, 1, 0x00, 0x01, 0xC2, 0x00, 0xFF, 0xF0};
    CHECK_EQ(n, sizeof m1);
    CHECK_MEM(msg, m1, sizeof m1);
    const uint8_t ff[] = {0xFF, 0xFF, 0xFF, 0xFF};
    CHECK_EQ(lf_telnet_cpc(LF_CPC_SET_BAUDRATE, ff, 4, msg), 14);

    /* an over-long SB is cut, not overflowed */
    lf_telnet t;
    lf_telnet_init(&t);
    uint8_t big[200], out[200];
    big[0] = 0xFF;
    big[1] = LF_TN_SB;
    memset(big + 2, 44, sizeof big - 4);
    big[198] = 0xFF;
    big[199] = LF_TN_SE;
    cmds c = {0};
    CHECK_EQ(lf_telnet_rx(&t, big, sizeof big, out, record, &c), 0);
    CHECK_EQ(c.n, 1);
    CHECK_EQ(c.sblen[0], LF_TN_SB_MAX - 1);

    /* an SB that never ends: dropped after LF_TN_SB_WIRE_MAX bytes, the
     * stream is data again (before, it swallowed everything for good) */
    static uint8_t endless[3 * LF_TN_SB_WIRE_MAX], eout[sizeof endless];
    endless[0] = 0xFF;
    endless[1] = LF_TN_SB;
    memset(endless + 2, 'x', sizeof endless - 2);
    lf_telnet_init(&t);
    size_t got = 0;
    for (size_t off = 0; off < sizeof endless; off += 100) {   /* across reads */
        size_t k = sizeof endless - off < 100 ? sizeof endless - off : 100;
        got += lf_telnet_rx(&t, endless + off, k, eout + got, NULL, NULL);
    }
    CHECK_EQ(t.sb_dropped, 1);
    CHECK_EQ(got, sizeof endless - 2 - LF_TN_SB_WIRE_MAX);
    CHECK_EQ(eout[0], 'x');
    CHECK_EQ(lf_telnet_rx(&t, (const uint8_t *)"\xff\xf1Q", 3, eout, NULL, NULL), 1);
    CHECK_EQ(eout[0], 'Q');
    CHECK_EQ(t.cmds, 2);   /* the SB and the NOP */
}

/* ---- servers on 127.0.0.1 -------------------------------------------------- */

enum srv_mode {
    SRV_RAW_ECHO,       /* echo every byte */
    SRV_RFC2217,        /* answer every option, echo data (unescaped, re-escaped) */
    SRV_NO_CONTROL,     /* like ser2net on a pty: never answers SET-CONTROL */
    SRV_REFUSE_BAUD,    /* answers SET-BAUDRATE with 9600 */
    SRV_NO_COMPORT,     /* answers WILL COM-PORT-OPTION with DONT */
    SRV_SILENT,         /* takes everything, says nothing */
};

typedef struct server {
    int lfd;
    int port;
    enum srv_mode mode;
    atomic_int stop;
    atomic_int accepted;
    atomic_int drop;            /* close the current connection now */
    pthread_t th;
} server;

typedef struct srv_conn {
    server *s;
    int fd;
} srv_conn;

static void send_all_fd(int fd, const uint8_t *b, size_t n)
{
    while (n) {
        ssize_t w = send(fd, b, n, MSG_NOSIGNAL);
        if (w <= 0)
            return;
        b += w;
        n -= (size_t)w;
    }
}

static void srv_cmd(void *ctx, uint8_t verb, uint8_t opt, const uint8_t *sb, size_t len)
{
    srv_conn *c = ctx;
    uint8_t r[16];
    size_t n = 0;
    if (verb == LF_TN_WILL) {
        int refuse = opt == LF_TN_OPT_COMPORT && c->s->mode == SRV_NO_COMPORT;
        r[n++] = 0xFF;
        r[n++] = refuse ? LF_TN_DONT : LF_TN_DO;
        r[n++] = opt;
    } else if (verb == LF_TN_DO) {
        r[n++] = 0xFF;
        r[n++] = opt == LF_TN_OPT_BINARY ? LF_TN_WILL : LF_TN_WONT;
        r[n++] = opt;
    } else if (verb == LF_TN_SB && opt == LF_TN_OPT_COMPORT && len >= 1) {
        uint8_t cmd = sb[0];
        if (cmd == LF_CPC_SET_CONTROL && c->s->mode == SRV_NO_CONTROL)
            return;
        if (cmd == LF_CPC_PURGE_DATA)
            return;   /* ser2net does not answer purges either */
        uint8_t val[4];
        size_t vlen = len - 1 > 4 ? 4 : len - 1;
        memcpy(val, sb + 1, vlen);
        if (cmd == LF_CPC_SET_BAUDRATE && c->s->mode == SRV_REFUSE_BAUD) {
            const uint8_t b9600[4] = {0, 0, 0x25, 0x80};
            memcpy(val, b9600, 4);
        }
        n = lf_telnet_cpc((uint8_t)(cmd + LF_CPC_SERVER), val, vlen, r);
    }
    if (n)
        send_all_fd(c->fd, r, n);
}

static void *server_main(void *arg)
{
    server *s = arg;
    while (!atomic_load(&s->stop)) {
        struct pollfd pf = {.fd = s->lfd, .events = POLLIN};
        if (poll(&pf, 1, 20) <= 0)
            continue;
        int fd = accept(s->lfd, NULL, NULL);
        if (fd < 0)
            continue;
        atomic_fetch_add(&s->accepted, 1);
        srv_conn c = {.s = s, .fd = fd};
        lf_telnet t;
        lf_telnet_init(&t);
        while (!atomic_load(&s->stop)) {
            if (atomic_exchange(&s->drop, 0)) {
                struct linger lg = {1, 0};   /* a RST, like a crashed server */
                setsockopt(fd, SOL_SOCKET, SO_LINGER, &lg, sizeof lg);
                break;
            }
            struct pollfd p2 = {.fd = fd, .events = POLLIN};
            if (poll(&p2, 1, 10) <= 0)
                continue;
            uint8_t in[1024], data[1024], enc[2048];
            ssize_t r = recv(fd, in, sizeof in, 0);
            if (r <= 0)
                break;
            if (s->mode == SRV_SILENT)
                continue;
            if (s->mode == SRV_RAW_ECHO) {
                send_all_fd(fd, in, (size_t)r);
                continue;
            }
            size_t d = lf_telnet_rx(&t, in, (size_t)r, data, srv_cmd, &c);
            send_all_fd(fd, enc, lf_telnet_escape(data, d, enc));
        }
        close(fd);
    }
    return NULL;
}

static int server_start(server *s, enum srv_mode mode)
{
    memset(s, 0, sizeof *s);
    s->mode = mode;
    s->lfd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    int one = 1;
    setsockopt(s->lfd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof a;
    if (bind(s->lfd, (struct sockaddr *)&a, sizeof a) < 0 || listen(s->lfd, 4) < 0 ||
        getsockname(s->lfd, (struct sockaddr *)&a, &len) < 0)
        return -1;
    s->port = ntohs(a.sin_port);
    return pthread_create(&s->th, NULL, server_main, s) == 0 ? 0 : -1;
}

static void server_stop(server *s)
{
    atomic_store(&s->stop, 1);
    pthread_join(s->th, NULL);
    close(s->lfd);
}

static int open_url(fap_port **p, const char *scheme, const server *s, const char *query,
                    fap_rs485_mode mode)
{
    char url[128];
    snprintf(url, sizeof url, "%s://127.0.0.1:%d%s", scheme, s->port, query ? query : "");
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = mode;
    return fap_port_open(p, url, &o);
}

/* Write every byte value (0xFF included), read it all back from the echo. */
static int echo_all_bytes(fap_port *p)
{
    uint8_t out[300], in[300];
    for (size_t i = 0; i < sizeof out; i++)
        out[i] = (uint8_t)(i < 256 ? i : (i & 1 ? 0xFF : 0x0D));
    if (fap_port_write(p, out, sizeof out) != (ssize_t)sizeof out)
        return -1;
    size_t got = 0;
    int64_t deadline = fap_port_now_ns() + WAIT_NS;
    while (got < sizeof in) {
        ssize_t r = fap_port_read(p, in + got, sizeof in - got, deadline);
        if (r <= 0)
            return -2;
        got += (size_t)r;
    }
    return memcmp(in, out, sizeof out) == 0 ? 0 : -3;
}

static void test_tcp_echo_and_drop(void)
{
    server s;
    REQUIRE(server_start(&s, SRV_RAW_ECHO) == 0);
    fap_port *p = NULL;
    REQUIRE(open_url(&p, "tcp", &s, NULL, FAP_RS485_AUTO) == 0);
    CHECK_EQ(fap_port_mode(p), FAP_RS485_NONE);      /* AUTO: the server's job */
    CHECK(fap_port_fd(p) >= 0);
    CHECK_EQ(echo_all_bytes(p), 0);
    CHECK_EQ(fap_port_warning(p, NULL, 0), 0);
    CHECK_EQ(lf_port_link_slack_ns(p), (lf_ns)LF_URL_RTT_MS_DEFAULT * LF_NS_PER_MS);
    CHECK_EQ(fap_port_caps(p), FAP_PORT_CAP_NETWORK);   /* not paced, no lock, no RTS */
    CHECK_EQ(fap_port_flush(p), 0);
    /* the server resets the connection: a vanished device, then a reopen */
    atomic_store(&s.drop, 1);
    uint8_t b[8];
    ssize_t r = fap_port_read(p, b, sizeof b, fap_port_now_ns() + WAIT_NS);
    CHECK(r == -EIO || r == -ECONNRESET);
    CHECK_EQ(fap_port_fd(p), -1);
    CHECK(fap_port_write(p, b, 1) < 0);
    CHECK_EQ(fap_port_reopen(p), 0);
    CHECK_EQ(echo_all_bytes(p), 0);
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.reopens, 1);
    CHECK(st.read_errors >= 1);
    fap_port_close(p);
    REQUIRE(open_url(&p, "tcp", &s, "?rtt_ms=0", FAP_RS485_NONE) == 0);
    CHECK_EQ(lf_port_link_slack_ns(p), 0);
    fap_port_close(p);
    server_stop(&s);
    /* the server is gone: refused, and a reopen says so */
    CHECK_EQ(open_url(&p, "tcp", &s, NULL, FAP_RS485_NONE), -ECONNREFUSED);
}

static void test_rfc2217_full_server(void)
{
    server s;
    REQUIRE(server_start(&s, SRV_RFC2217) == 0);
    fap_port *p = NULL;
    REQUIRE(open_url(&p, "rfc2217", &s, NULL, FAP_RS485_NONE) == 0);
    CHECK_EQ(fap_port_warning(p, NULL, 0), 0);      /* everything answered */
    CHECK_EQ(echo_all_bytes(p), 0);
    CHECK_EQ(fap_port_flush(p), 0);                  /* PURGE-DATA, unanswered: fine */
    CHECK_EQ(echo_all_bytes(p), 0);
    fap_port_close(p);
    server_stop(&s);
}

static void test_rfc2217_unanswered_control_warns(void)
{
    server s;
    REQUIRE(server_start(&s, SRV_NO_CONTROL) == 0);
    fap_port *p = NULL;
    int64_t t0 = fap_port_now_ns();
    REQUIRE(open_url(&p, "rfc2217", &s, "?option_ms=50", FAP_RS485_NONE) == 0);
    CHECK(fap_port_now_ns() - t0 < 5 * LF_NS_PER_S);  /* bounded, no hang */
    char note[256];
    CHECK(fap_port_warning(p, note, sizeof note) > 0);
    CHECK(strstr(note, "SET-CONTROL") != NULL);
    char tiny[4];
    CHECK(fap_port_warning(p, tiny, sizeof tiny) > 3);
    CHECK_EQ(strlen(tiny), 3);                       /* cut, terminated */
    CHECK_EQ(echo_all_bytes(p), 0);
    fap_port_close(p);
    server_stop(&s);
}

static void test_rfc2217_refusals_are_errors(void)
{
    server s;
    fap_port *p = NULL;
    REQUIRE(server_start(&s, SRV_REFUSE_BAUD) == 0);
    CHECK_EQ(open_url(&p, "rfc2217", &s, NULL, FAP_RS485_NONE), FAP_PORT_EREFUSED);
    server_stop(&s);
    REQUIRE(server_start(&s, SRV_NO_COMPORT) == 0);
    CHECK_EQ(open_url(&p, "rfc2217", &s, NULL, FAP_RS485_NONE), FAP_PORT_EREFUSED);
    server_stop(&s);
    /* a server that says no word of Telnet within option_ms (a raw TCP
     * port): refused, never used with the negotiation landing on its bus */
    REQUIRE(server_start(&s, SRV_SILENT) == 0);
    int64_t t0 = fap_port_now_ns();
    CHECK_EQ(open_url(&p, "rfc2217", &s, "?option_ms=30", FAP_RS485_NONE), -EPROTO);
    CHECK(fap_port_now_ns() - t0 < 2 * LF_NS_PER_S);
    server_stop(&s);
}

static void test_open_errors(void)
{
    fap_port *p = NULL;
    fap_port_options o;
    fap_port_options_init(&o);
    CHECK_EQ(fap_port_open(&p, "tcp://", &o), FAP_PORT_EURL);
    CHECK_EQ(fap_port_open(&p, "tcp://host", &o), FAP_PORT_EURL);
    CHECK_EQ(fap_port_open(&p, "tcp://host:99999", &o), FAP_PORT_EURL);
    CHECK_EQ(fap_port_open(&p, "nope://host:1", &o), FAP_PORT_EURL);
    CHECK_EQ(fap_port_open(&p, "tcp://no-such-host.invalid:1", &o), FAP_PORT_ERESOLVE);
    o.rs485_mode = FAP_RS485_KERNEL;
    CHECK_EQ(fap_port_open(&p, "tcp://127.0.0.1:1", &o), FAP_PORT_ENET485);
    o.rs485_mode = FAP_RS485_SOFT_RTS;
    CHECK_EQ(fap_port_open(&p, "rfc2217://127.0.0.1:1", &o), FAP_PORT_ENET485);
    o.rs485_mode = FAP_RS485_NONE;
    o.baud = 12345;
    CHECK_EQ(fap_port_open(&p, "tcp://127.0.0.1:1", &o), -EINVAL);
    CHECK(p == NULL);
    CHECK(strstr(fap_port_strerror(FAP_PORT_EURL), "URL") != NULL);
    CHECK(strstr(fap_port_strerror(FAP_PORT_ENET485), "server") != NULL);
    CHECK(strstr(fap_port_strerror(FAP_PORT_EREFUSED), "refused") != NULL);
    CHECK(strstr(fap_port_strerror(FAP_PORT_ERESOLVE), "host") != NULL);
    CHECK_EQ(fap_port_warning(NULL, NULL, 0), 0);
    CHECK_EQ(lf_port_link_slack_ns(NULL), 0);
}

UNIT_MAIN(UNIT(test_url_parse), UNIT(test_telnet_codec), UNIT(test_tcp_echo_and_drop),
          UNIT(test_rfc2217_full_server), UNIT(test_rfc2217_unanswered_control_warns),
          UNIT(test_rfc2217_refusals_are_errors), UNIT(test_open_errors))
