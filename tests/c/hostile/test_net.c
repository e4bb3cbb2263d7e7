/* Hostile input for the network transports' public entry points:
 * fap_port_open with URLs (tcp://, rfc2217://) of every broken shape,
 * fap_port_warning with NULL and tiny buffers, the classic fapInit with a
 * URL, and a server that closes at once or sends Telnet garbage. Every call
 * returns a documented code, never crashes, never hangs. */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdint.h>
#include <sys/socket.h>
#include <unistd.h>

#include "fap.h"
#include "fap_port.h"
#include "unit.h"

static int documented(int r)
{
    return r == FAP_PORT_EURL || r == FAP_PORT_ERESOLVE || r == FAP_PORT_ENET485 ||
           r == FAP_PORT_EREFUSED || r == -ECONNREFUSED || r == -EINVAL || r == -ETIMEDOUT ||
           r == -EIO || r == -ENOENT || r == -EADDRNOTAVAIL || r == -ENETUNREACH;
}

static void test_broken_urls(void)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = FAP_RS485_NONE;
    fap_port *p = NULL;
    const char *urls[] = {
        "tcp://", "rfc2217://", "://", "tcp:/", "tcp://:", "tcp://[", "tcp://[]:1",
        "tcp://[::1]", "tcp://127.0.0.1:", "tcp://127.0.0.1:-1", "tcp://127.0.0.1:65536",
        "tcp://127.0.0.1:1?connect_ms=99999999999999999999", "tcp://127.0.0.1:1?&",
        "tcp://127.0.0.1:1?=", "tcp://127.0.0.1:1??", "tcp://127.0.0.1:1#frag",
        "TCP://127.0.0.1:1", "tcp://127.0.0.1:1\n", "rfc2217://127.0.0.1:1?option_ms=1x",
    };
    for (size_t i = 0; i < sizeof urls / sizeof urls[0]; i++) {
        int r = fap_port_open(&p, urls[i], &o);
        if (!documented(r))
            fprintf(stderr, "%s -> %d\n", urls[i], r);
        CHECK(documented(r));
        CHECK(p == NULL);
    }
    /* a very long URL, and every byte value in the port field */
    static char big[1 << 16];
    memcpy(big, "tcp://", 6);
    memset(big + 6, 'a', sizeof big - 7);
    big[sizeof big - 1] = '\0';
    CHECK_EQ(fap_port_open(&p, big, &o), FAP_PORT_EURL);
    char u[32];
    for (int b = 1; b < 256; b++) {
        snprintf(u, sizeof u, "tcp://127.0.0.1:1%c", b);
        int r = fap_port_open(&p, u, &o);
        CHECK(documented(r) || r == -ECONNREFUSED);
        if (r == 0)
            fap_port_close(p);
    }
    CHECK(fap_port_open(NULL, "tcp://127.0.0.1:1", &o) < 0);
    CHECK_EQ(fap_port_warning(NULL, u, sizeof u), 0);
    CHECK_EQ(u[0], '\0');
    CHECK_EQ(fap_port_warning(NULL, NULL, 100), 0);
}

/* A server that accepts and then misbehaves. */
typedef struct bad_server {
    int lfd, port, kind;
    pthread_t th;
} bad_server;

static void *bad_main(void *arg)
{
    bad_server *s = arg;
    for (int k = 0; k < 2; k++) {
        struct pollfd pf = {.fd = s->lfd, .events = POLLIN};
        if (poll(&pf, 1, 5000) <= 0)
            return NULL;
        int fd = accept(s->lfd, NULL, NULL);
        if (fd < 0)
            return NULL;
        if (s->kind == 1) {   /* Telnet garbage: IAC SB without end, lone IACs, bogus options */
            uint8_t junk[600];
            for (size_t i = 0; i < sizeof junk; i++)
                junk[i] = (uint8_t)(i % 3 == 0 ? 0xFF : (i * 37) & 0xFF);
            if (send(fd, junk, sizeof junk, MSG_NOSIGNAL) < 0) { /* the client left */ }
        }
        close(fd);            /* kind 0: close at once */
    }
    return NULL;
}

static int bad_start(bad_server *s, int kind)
{
    memset(s, 0, sizeof *s);
    s->kind = kind;
    s->lfd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof a;
    if (bind(s->lfd, (struct sockaddr *)&a, sizeof a) < 0 || listen(s->lfd, 2) < 0 ||
        getsockname(s->lfd, (struct sockaddr *)&a, &len) < 0)
        return -1;
    s->port = ntohs(a.sin_port);
    return pthread_create(&s->th, NULL, bad_main, s);
}

static void test_misbehaving_servers(void)
{
    for (int kind = 0; kind < 2; kind++) {
        for (int sch = 0; sch < 2; sch++) {
            bad_server s;
            REQUIRE(bad_start(&s, kind) == 0);
            char url[64];
            snprintf(url, sizeof url, "%s://127.0.0.1:%d?option_ms=50",
                     sch ? "rfc2217" : "tcp", s.port);
            fap_port_options o;
            fap_port_options_init(&o);
            fap_port *p = NULL;
            int r = fap_port_open(&p, url, &o);
            if (r == 0) {
                uint8_t b[64];
                char note[8];
                (void)fap_port_warning(p, note, sizeof note);
                CHECK(strlen(note) < sizeof note);
                ssize_t n;
                int64_t dl = fap_port_now_ns() + 2000000000LL;
                while ((n = fap_port_read(p, b, sizeof b, dl)) > 0) { /* drain */ }
                CHECK(n == 0 || n == -EIO);
                (void)fap_port_write(p, b, sizeof b);
                (void)fap_port_reopen(p);
                fap_port_close(p);
            } else {
                CHECK(documented(r));
            }
            pthread_join(s.th, NULL);
            close(s.lfd);
        }
    }
}

/* The classic API takes the URL as its device string. */
static void test_classic_url(void)
{
    char bad[] = "tcp://", refused[] = "tcp://127.0.0.1:1";
    CHECK(fapInit(bad, 115200) != GOOD);
    CHECK(fapInit(refused, 115200) != GOOD);
}

UNIT_MAIN(UNIT(test_broken_urls), UNIT(test_misbehaving_servers), UNIT(test_classic_url))
