/* Hostile input for the network transports' public entry points:
 * fap_port_open with URLs (tcp://, rfc2217://) of every broken shape,
 * fap_port_warning with NULL and tiny buffers, the classic fapInit with a
 * URL, and a server that closes at once or sends Telnet garbage. Every call
 * returns a documented code, never crashes, never hangs. */
#include <arpa/inet.h>
#include <net/if.h>
#include <sched.h>
#include <sys/ioctl.h>
#include <sys/mount.h>
#include <sys/wait.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include "fap.h"
#include "fap_port.h"
#include "unit.h"

static int documented(int r)
{
    return r == FAP_PORT_EURL || r == FAP_PORT_ERESOLVE || r == FAP_PORT_ENET485 ||
           r == FAP_PORT_EREFUSED || r == -ECONNREFUSED || r == -EINVAL || r == -ETIMEDOUT ||
           r == -EIO || r == -ENOENT || r == -EADDRNOTAVAIL || r == -ENETUNREACH ||
           r == -EPROTO || r == -ECANCELED;
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
            shutdown(s.lfd, SHUT_RDWR);   /* no second client coming: the server's wait ends */
            pthread_join(s.th, NULL);
            close(s.lfd);
        }
    }
}

/* ---- hostile RFC 2217 servers: every open, read, write and close ends ----
 *
 * Each server floods the client with Telnet (or takes its bytes and never
 * reads again) and never stops by itself; the test measures that open,
 * cancel and close return within BOUND_NS. Before the fix a flood kept
 * telnet_recv looping with no deadline (the open never returned) and a
 * send to a server that does not read waited 2 s past a close. */

#define BOUND_NS (1500 * 1000000LL)   /* generous for a loaded 2-core machine */

enum flood {
    FLOOD_NOP,          /* IAC NOP forever */
    FLOOD_DODONT,       /* IAC DO BINARY / IAC DONT BINARY forever, never reads */
    FLOOD_SB,           /* IAC SB COM-PORT then bytes, never IAC SE */
    FLOOD_AFTER_OPEN,   /* a good negotiation, then IAC NOP forever */
    NO_READ_AFTER_OPEN, /* a good negotiation, then never reads again */
};

typedef struct hostile {
    int lfd, port;
    enum flood kind;
    atomic_int stop;
    pthread_t th;
} hostile;

/* What a server answers up front, unasked: DO/WILL BINARY, DO COM-PORT. */
static const uint8_t good_hello[] = {0xFF, 253, 0, 0xFF, 251, 0, 0xFF, 253, 44};

/* Read until the client's last open setting (SET-CONTROL RTS on) went by. */
static int await_settings(hostile *s, int fd)
{
    static const uint8_t last[] = {0xFF, 250, 44, 5, 11, 0xFF, 240};
    uint8_t win[sizeof last] = {0};
    while (!atomic_load(&s->stop)) {
        struct pollfd pf = {.fd = fd, .events = POLLIN};
        if (poll(&pf, 1, 20) <= 0)
            continue;
        uint8_t b;
        if (recv(fd, &b, 1, 0) <= 0)
            return -1;
        memmove(win, win + 1, sizeof win - 1);
        win[sizeof win - 1] = b;
        if (memcmp(win, last, sizeof last) == 0)
            return 0;
    }
    return -1;
}

static void *hostile_main(void *arg)
{
    hostile *s = arg;
    while (!atomic_load(&s->stop)) {
        struct pollfd pf = {.fd = s->lfd, .events = POLLIN};
        if (poll(&pf, 1, 20) <= 0)
            continue;
        int fd = accept(s->lfd, NULL, NULL);
        if (fd < 0)
            continue;
        uint8_t buf[4096];
        size_t n = 0;
        switch (s->kind) {
        case FLOOD_NOP:
        case FLOOD_AFTER_OPEN:
            for (; n + 1 < sizeof buf; n += 2) {
                buf[n] = 0xFF;
                buf[n + 1] = 241;   /* NOP */
            }
            break;
        case FLOOD_DODONT:
            for (; n + 5 < sizeof buf; n += 6)
                memcpy(buf + n, (const uint8_t[]){0xFF, 253, 0, 0xFF, 254, 0}, 6);
            break;
        case FLOOD_SB:
            memcpy(buf, (const uint8_t[]){0xFF, 250, 44}, 3);
            memset(buf + 3, 'x', sizeof buf - 3);
            n = sizeof buf;
            break;
        case NO_READ_AFTER_OPEN:
            break;
        }
        int ok = 1;
        if (s->kind == FLOOD_AFTER_OPEN || s->kind == NO_READ_AFTER_OPEN) {
            ok = send(fd, good_hello, sizeof good_hello, MSG_NOSIGNAL) > 0 &&
                 await_settings(s, fd) == 0;
        }
        const uint8_t *more = s->kind == FLOOD_SB ? buf + 3 : buf;
        size_t more_n = s->kind == FLOOD_SB ? n - 3 : n;
        int first = 1;
        while (ok && !atomic_load(&s->stop)) {
            if (s->kind == NO_READ_AFTER_OPEN) {   /* hold the connection, read nothing */
                poll(NULL, 0, 20);
                continue;
            }
            struct pollfd po = {.fd = fd, .events = POLLOUT};
            if (poll(&po, 1, 20) <= 0)
                continue;
            ssize_t w = first ? send(fd, buf, n, MSG_NOSIGNAL | MSG_DONTWAIT)
                              : send(fd, more, more_n, MSG_NOSIGNAL | MSG_DONTWAIT);
            if (w < 0 && errno != EAGAIN)
                break;
            first = 0;
        }
        close(fd);
    }
    return NULL;
}

static int hostile_start(hostile *s, enum flood kind)
{
    memset(s, 0, sizeof *s);
    s->kind = kind;
    s->lfd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof a;
    if (bind(s->lfd, (struct sockaddr *)&a, sizeof a) < 0 || listen(s->lfd, 4) < 0 ||
        getsockname(s->lfd, (struct sockaddr *)&a, &len) < 0)
        return -1;
    s->port = ntohs(a.sin_port);
    return pthread_create(&s->th, NULL, hostile_main, s) == 0 ? 0 : -1;
}

static void hostile_stop(hostile *s)
{
    atomic_store(&s->stop, 1);
    pthread_join(s->th, NULL);
    close(s->lfd);
}

/* Write the eventfd once, after ms (a second thread: the close or Ctrl-C). */
typedef struct kicker {
    int efd, ms;
    pthread_t th;
} kicker;

static void *kick_main(void *arg)
{
    kicker *k = arg;
    poll(NULL, 0, k->ms);
    uint64_t one = 1;
    if (write(k->efd, &one, sizeof one) < 0) { /* cannot fail */ }
    return NULL;
}

static void kick_start(kicker *k, int efd, int ms)
{
    k->efd = efd;
    k->ms = ms;
    pthread_create(&k->th, NULL, kick_main, k);
}

static void test_telnet_floods_end_the_open(void)
{
    const enum flood kinds[] = {FLOOD_NOP, FLOOD_DODONT, FLOOD_SB};
    for (size_t i = 0; i < sizeof kinds / sizeof kinds[0]; i++) {
        hostile s;
        REQUIRE(hostile_start(&s, kinds[i]) == 0);
        fap_port_options o;
        fap_port_options_init(&o);
        char url[96];
        /* bounded by option_ms: the open ends, with whatever it concluded */
        snprintf(url, sizeof url, "rfc2217://127.0.0.1:%d?option_ms=200", s.port);
        fap_port *p = NULL;
        int64_t t0 = fap_port_now_ns();
        int r = fap_port_open(&p, url, &o);
        int64_t took = fap_port_now_ns() - t0;
        if (took >= BOUND_NS)
            fprintf(stderr, "flood %zu: open took %.3f s\n", i, took / 1e9);
        CHECK(took < BOUND_NS);
        CHECK(r == 0 || documented(r));
        if (r == 0) {
            uint8_t b[64];
            t0 = fap_port_now_ns();
            ssize_t n = fap_port_read(p, b, sizeof b, t0 + 100 * 1000000LL);
            CHECK(n >= 0 || documented((int)n));
            CHECK(fap_port_now_ns() - t0 < BOUND_NS);
            fap_port_close(p);
        }
        /* a long option_ms: a cancel from another thread ends the open */
        snprintf(url, sizeof url, "rfc2217://127.0.0.1:%d?option_ms=600000", s.port);
        int efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
        kicker k;
        kick_start(&k, efd, 100);
        p = NULL;
        t0 = fap_port_now_ns();
        r = fap_port_open_cancellable(&p, url, &o, &efd);
        took = fap_port_now_ns() - t0;
        pthread_join(k.th, NULL);
        if (took >= BOUND_NS)
            fprintf(stderr, "flood %zu: cancelled open took %.3f s\n", i, took / 1e9);
        CHECK(took < BOUND_NS);
        CHECK_EQ(r, -ECANCELED);
        CHECK(p == NULL);
        close(efd);
        hostile_stop(&s);
    }
}

/* A flood after a good open: reads keep their deadline, a cancel ends a
 * read that waits forever, and close() returns. */
static void *read_forever(void *arg)
{
    fap_port *p = arg;
    uint8_t b[64];
    ssize_t n;
    while ((n = fap_port_read(p, b, sizeof b, INT64_MAX)) > 0) { /* data: none sent */ }
    return (void *)(intptr_t)n;
}

static void test_flood_after_open(void)
{
    hostile s;
    REQUIRE(hostile_start(&s, FLOOD_AFTER_OPEN) == 0);
    char url[96];
    snprintf(url, sizeof url, "rfc2217://127.0.0.1:%d?option_ms=50", s.port);
    fap_port_options o;
    fap_port_options_init(&o);
    int efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    fap_port *p = NULL;
    REQUIRE(fap_port_open_cancellable(&p, url, &o, &efd) == 0);
    uint8_t b[64];
    int64_t t0 = fap_port_now_ns();
    CHECK_EQ(fap_port_read(p, b, sizeof b, t0 + 100 * 1000000LL), 0);   /* no data: only NOPs */
    CHECK(fap_port_now_ns() - t0 < BOUND_NS);
    CHECK_EQ(fap_port_read(p, b, sizeof b, 0), 0);                         /* no wait: at once */
    pthread_t th;
    pthread_create(&th, NULL, read_forever, p);
    kicker k;
    t0 = fap_port_now_ns();
    kick_start(&k, efd, 100);
    void *res;
    pthread_join(th, &res);
    CHECK_EQ((intptr_t)res, -ECANCELED);
    fap_port_close(p);
    CHECK(fap_port_now_ns() - t0 < BOUND_NS);
    pthread_join(k.th, NULL);
    close(efd);
    hostile_stop(&s);
}

/* A server that stopped reading: a write fills the socket and waits for
 * room; the cancel fd (a close) ends it at once, not after the 2 s send
 * wait. */
static void *write_lots(void *arg)
{
    fap_port *p = arg;
    static uint8_t big[1 << 20];
    memset(big, 0xFF, sizeof big);   /* every byte doubled on the wire */
    ssize_t w = 0;
    for (int i = 0; i < 64 && w >= 0; i++)
        w = fap_port_write(p, big, sizeof big);
    return (void *)(intptr_t)w;
}

static void test_write_to_server_that_does_not_read(void)
{
    hostile s;
    REQUIRE(hostile_start(&s, NO_READ_AFTER_OPEN) == 0);
    char url[96];
    snprintf(url, sizeof url, "rfc2217://127.0.0.1:%d?option_ms=50", s.port);
    fap_port_options o;
    fap_port_options_init(&o);
    o.write_timeout_us = 600000000u;   /* the port's own bound out of the way */
    int efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    fap_port *p = NULL;
    REQUIRE(fap_port_open_cancellable(&p, url, &o, &efd) == 0);
    pthread_t th;
    pthread_create(&th, NULL, write_lots, p);
    poll(NULL, 0, 300);   /* let it fill the socket (a cancel before then ends it too) */
    int64_t t0 = fap_port_now_ns();
    uint64_t one = 1;
    CHECK_EQ(write(efd, &one, sizeof one), 8);
    void *res;
    pthread_join(th, &res);
    fap_port_close(p);
    int64_t took = fap_port_now_ns() - t0;
    if (took >= 1000000000LL)
        fprintf(stderr, "write: cancel to return %.3f s\n", took / 1e9);
    CHECK(took < 1000000000LL);   /* before: up to SEND_WAIT_MS (2 s) per chunk */
    CHECK_EQ((intptr_t)res, -ECANCELED);
    close(efd);
    hostile_stop(&s);
}

/* rfc2217:// on a raw TCP server that says nothing: refused with EPROTO
 * (it would take the negotiation as bus data); one that closes at once: EIO. */
static void test_raw_server_refused(void)
{
    bad_server s;
    REQUIRE(bad_start(&s, 0) == 0);   /* closes at once */
    char url[96];
    snprintf(url, sizeof url, "rfc2217://127.0.0.1:%d?option_ms=100", s.port);
    fap_port_options o;
    fap_port_options_init(&o);
    fap_port *p = NULL;
    CHECK_EQ(fap_port_open(&p, url, &o), -EIO);
    shutdown(s.lfd, SHUT_RDWR);   /* bad_main's second accept: ends at once */
    pthread_join(s.th, NULL);
    close(s.lfd);
    hostile h;
    REQUIRE(hostile_start(&h, NO_READ_AFTER_OPEN) == 0);   /* answers the hello: fine */
    snprintf(url, sizeof url, "rfc2217://127.0.0.1:%d?option_ms=50", h.port);
    REQUIRE(fap_port_open(&p, url, &o) == 0);
    fap_port_close(p);
    hostile_stop(&h);
}

/* ---- a DNS server that never answers --------------------------------------
 *
 * In a child with its own mount and network namespaces (root only: skipped
 * otherwise), /etc/resolv.conf is bind-mounted over by one that names
 * 127.0.0.1, where a UDP socket takes the queries and answers none. glibc's
 * getaddrinfo then waits its timeout x attempts (10 s); the open must end
 * at connect_ms, and at once on a cancel. Before the fix: 10.0 s. */

static int fake_dns_enter(void)
{
    if (geteuid() != 0 || unshare(CLONE_NEWNS | CLONE_NEWNET) < 0)
        return -1;
    if (mount("none", "/", NULL, MS_REC | MS_PRIVATE, NULL) < 0)
        return -1;
    char conf[] = "/tmp/fap_resolv_XXXXXX";
    int fd = mkstemp(conf);
    if (fd < 0)
        return -1;
    const char text[] = "nameserver 127.0.0.1\n";
    int ok = write(fd, text, sizeof text - 1) == (ssize_t)(sizeof text - 1);
    close(fd);
    ok = ok && mount(conf, "/etc/resolv.conf", NULL, MS_BIND, NULL) == 0;
    unlink(conf);   /* the mount keeps it */
    if (!ok)
        return -1;
    int s = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    struct ifreq ifr;
    memset(&ifr, 0, sizeof ifr);
    snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "lo");
    ok = ioctl(s, SIOCGIFFLAGS, &ifr) == 0;
    ifr.ifr_flags |= IFF_UP;
    ok = ok && ioctl(s, SIOCSIFFLAGS, &ifr) == 0;
    close(s);
    if (!ok)
        return -1;
    /* the server: takes every query, answers none (kept open until exit) */
    int u = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons(53),
                            .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    return bind(u, (struct sockaddr *)&a, sizeof a);
}

static void dns_checks(void)
{
    fap_port_options o;
    fap_port_options_init(&o);
    fap_port *p = NULL;
    int64_t t0 = fap_port_now_ns();
    CHECK_EQ(fap_port_open(&p, "tcp://fap-dns-test.example:4001?connect_ms=300", &o),
             FAP_PORT_ERESOLVE);
    int64_t took = fap_port_now_ns() - t0;
    fprintf(stderr, "dns: open at connect_ms=300 took %.3f s\n", took / 1e9);
    CHECK(took >= 290 * 1000000LL);
    CHECK(took < BOUND_NS);
    /* a cancel (close, Ctrl-C) ends the lookup's wait at once */
    int efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    kicker k;
    kick_start(&k, efd, 100);
    t0 = fap_port_now_ns();
    CHECK_EQ(fap_port_open_cancellable(&p, "rfc2217://fap-dns-test.example:4001?connect_ms=60000",
                                       &o, &efd), -ECANCELED);
    took = fap_port_now_ns() - t0;
    fprintf(stderr, "dns: cancelled open took %.3f s\n", took / 1e9);
    CHECK(took < BOUND_NS);
    pthread_join(k.th, NULL);
    close(efd);
    /* numeric hosts never wait for DNS */
    t0 = fap_port_now_ns();
    CHECK_EQ(fap_port_open(&p, "tcp://127.0.0.1:1?connect_ms=300", &o), -ECONNREFUSED);
    CHECK(fap_port_now_ns() - t0 < BOUND_NS);
}

static void test_dns_that_never_answers(void)
{
    pid_t pid = fork();
    REQUIRE(pid >= 0);
    if (pid == 0) {
        if (fake_dns_enter() < 0)
            _exit(77);   /* not root, or no namespaces here */
        dns_checks();
        fflush(stderr);
        _exit(unit_failed ? 1 : 0);
    }
    int st = 0;
    REQUIRE(waitpid(pid, &st, 0) == pid);
    if (WIFEXITED(st) && WEXITSTATUS(st) == 77) {
        fprintf(stderr, "skip test_dns_that_never_answers: needs root and unshare(2)\n");
        return;
    }
    CHECK(WIFEXITED(st) && WEXITSTATUS(st) == 0);
}

/* The classic API takes the URL as its device string. */
static void test_classic_url(void)
{
    char bad[] = "tcp://", refused[] = "tcp://127.0.0.1:1";
    CHECK(fapInit(bad, 115200) != GOOD);
    CHECK(fapInit(refused, 115200) != GOOD);
}

UNIT_MAIN(UNIT(test_broken_urls), UNIT(test_misbehaving_servers), UNIT(test_classic_url),
          UNIT(test_telnet_floods_end_the_open), UNIT(test_flood_after_open),
          UNIT(test_write_to_server_that_does_not_read), UNIT(test_raw_server_refused), UNIT(test_dns_that_never_answers))
