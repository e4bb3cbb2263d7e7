/* port_net.c - tcp:// and rfc2217:// as a port-layer transport (the
 * line-level table, port_backend.h; see port_net.h, docs/port.md "Network
 * transports").
 *
 * The open connects a socket and hands back its fd; read/write/poll work
 * on it as on a tty. set_line is the RFC 2217 line settings at the baud
 * (raw TCP: the server's own are in force), flush reads the socket empty
 * (RFC 2217 also asks the server to purge), drain has nothing to wait for.
 * No rs485, rts, lock or tx_empty: a socket has no RS-485 config (AUTO
 * settles on NONE), direction is the server's job, and a connection is
 * ours alone (the server decides who connects). A dropped connection reads
 * as end of file or a reset, reported as EIO: the layer's "device
 * vanished", so every engine's reopen reconnects. */
#include "port/port_net.h"

#include <fcntl.h>
#include <netdb.h>
#include <signal.h>
#include <sys/eventfd.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <errno.h>
#include <pthread.h>

#include "common/mono_clock.h"
#include "port/port_telnet.h"

/* Keepalive: a server that vanished without a reset (power cut, cable)
 * is found within about 5 s of silence; unacknowledged data, within
 * TCP_USER_TIMEOUT. */
#define KEEP_IDLE_S 2
#define KEEP_INTVL_S 1
#define KEEP_CNT 3
#define USER_TIMEOUT_MS 5000
/* The longest a send may wait for room in the socket buffer. */
#define SEND_WAIT_MS 2000
/* Telnet answers (WILL/WONT/DO/DONT) one connection sends at most: a real
 * server negotiates a handful of options once; one that flips an option
 * back and forth forever gets no more answers after these. */
#define ANSWER_MAX 64

enum { OPT_OFF = 0, OPT_ASKED, OPT_ON, OPT_REFUSED };

struct lf_lookup;

typedef struct lf_net {
    lf_port_url url;
    int fd;                       /* the connection, -1 when none */
    const int *const *cancel;     /* the port's cancel fd pointer (net_attach) */
    pthread_mutex_t tx_mu;        /* one sender: data and Telnet answers */
    pthread_mutex_t st_mu;        /* warning[] */
    pthread_mutex_t ans_mu;       /* ans[] (never held across a wait) */
    char warning[400];
    /* Telnet answers the parser queued: sent without waiting by the reader
     * (when no data send is in progress) or before the next data send. */
    uint8_t ans[96];
    size_t ans_len;
    unsigned answers;             /* answers queued on this connection */
    struct lf_lookup *lookup;     /* a name lookup an open stopped waiting for */
    /* RFC 2217 (stream state: used under the port's rx_mu or at open) */
    lf_telnet tn;
    uint8_t us[256], him[256];    /* option states, OPT_* */
    unsigned answered[16];        /* answers per COM-PORT command (cmd - 100) */
    uint32_t answer_val[16];      /* the first answer's value since the settings went out */
    unsigned baud;                /* what set_line was given */
    int purged;                   /* set_line sent PURGE-DATA: the open's flush need not */
} lf_net;

/* Add a note to this connection's warning ("" clears it). */
static void set_warning(lf_net *c, const char *text)
{
    pthread_mutex_lock(&c->st_mu);
    size_t len = text[0] ? strlen(c->warning) : 0;
    snprintf(c->warning + len, sizeof c->warning - len, "%s%s", len ? "; " : "", text);
    pthread_mutex_unlock(&c->st_mu);
}

/* Errors that mean the connection is gone: reported as EIO, the port
 * layer's "device vanished" (port_internal.h), so it is reopened. */
static void map_gone(void)
{
    switch (errno) {
    case ECONNRESET: case EPIPE: case ETIMEDOUT: case ENOTCONN: case ECONNABORTED:
    case EHOSTUNREACH: case ENETUNREACH: case ENETDOWN: case EHOSTDOWN:
        errno = EIO;
        break;
    default:
        break;
    }
}

/* The port's cancel fd (readable: stop), -1 when it has none. */
static int cancel_fd_of(const lf_net *c)
{
    const int *p = c->cancel ? *c->cancel : NULL;
    return p ? *p : -1;
}

/* Wait for events on fd (fd < 0: only the cancel fd and the deadline):
 * the revents (> 0), 0 at the deadline, or -1 with errno (ECANCELED: the
 * port's cancel fd turned readable). Every wait of an open and of a send
 * is this one, so none outlives its deadline or a close. */
static int net_wait(const lf_net *c, int fd, short events, int64_t deadline)
{
    for (;;) {
        int64_t now = lf_now_ns();
        if (now >= deadline)
            return 0;
        struct pollfd pf[2] = {{.fd = fd, .events = events},
                               {.fd = cancel_fd_of(c), .events = POLLIN}};
        int r = poll(pf, 2, lf_poll_timeout_ms(deadline, now));
        if (r < 0 && errno != EINTR)
            return -1;
        if (r > 0 && pf[1].revents) {
            errno = ECANCELED;
            return -1;
        }
        if (r > 0 && pf[0].revents)
            return pf[0].revents;
    }
}

/* Queue a Telnet answer (bounded: see ANSWER_MAX). */
static void ans_queue(lf_net *c, const uint8_t *b, size_t n)
{
    pthread_mutex_lock(&c->ans_mu);
    if (c->answers < ANSWER_MAX && c->ans_len + n <= sizeof c->ans) {
        memcpy(c->ans + c->ans_len, b, n);
        c->ans_len += n;
        c->answers++;
    }
    pthread_mutex_unlock(&c->ans_mu);
}

/* Send queued answers without waiting (tx_mu held, so they never split a
 * data chunk): 0 when none is left, -1 with errno (EAGAIN: some are). */
static int ans_push(lf_net *c, int fd)
{
    int err = 0;
    pthread_mutex_lock(&c->ans_mu);
    while (c->ans_len) {
        ssize_t w = send(fd, c->ans, c->ans_len, MSG_NOSIGNAL | MSG_DONTWAIT);
        if (w > 0) {
            memmove(c->ans, c->ans + w, c->ans_len - (size_t)w);
            c->ans_len -= (size_t)w;
        } else if (w < 0 && errno == EINTR) {
            continue;
        } else {
            if (w < 0 && errno != EAGAIN && errno != EWOULDBLOCK)
                map_gone();
            err = w < 0 && errno != EWOULDBLOCK ? errno : EAGAIN;
            break;
        }
    }
    pthread_mutex_unlock(&c->ans_mu);
    if (err) {
        errno = err;
        return -1;
    }
    return 0;
}

/* The reader's turn to send queued answers: only if no data send holds
 * the line (that one sends them first), and never waiting. */
static void ans_flush_nowait(lf_net *c, int fd)
{
    if (pthread_mutex_trylock(&c->tx_mu) != 0)
        return;
    (void)ans_push(c, fd);   /* a failure shows on the next read or send */
    pthread_mutex_unlock(&c->tx_mu);
}

/* Send all n bytes (the socket is non-blocking), queued answers first;
 * bounded by deadline and by the port's cancel fd (ECANCELED). */
static int send_all(lf_net *c, int fd, const uint8_t *buf, size_t n, int64_t deadline)
{
    pthread_mutex_lock(&c->tx_mu);
    size_t off = 0;
    int err = 0;
    for (;;) {
        if (ans_push(c, fd) == 0) {
            if (off >= n)
                break;
            ssize_t w = send(fd, buf + off, n - off, MSG_NOSIGNAL | MSG_DONTWAIT);
            if (w > 0) {
                off += (size_t)w;
                continue;
            }
            if (w < 0 && errno == EINTR)
                continue;
            if (w < 0 && errno != EAGAIN && errno != EWOULDBLOCK) {
                map_gone();
                err = errno;
                break;
            }
        } else if (errno != EAGAIN) {
            err = errno;
            break;
        }
        int wr = net_wait(c, fd, POLLOUT, deadline);
        if (wr <= 0) {
            err = wr == 0 ? ETIMEDOUT : errno;
            break;
        }
    }
    pthread_mutex_unlock(&c->tx_mu);
    if (err) {
        errno = err;
        return -1;
    }
    return 0;
}

/* A send of this connection's own (Telnet commands, data), from now. */
static int64_t send_deadline(void)
{
    return lf_now_ns() + (int64_t)SEND_WAIT_MS * LF_NS_PER_MS;
}

/* ---- Telnet option negotiation (the client's side) --------------------- */

/* Answer the server: queued, sent by telnet_recv or the next send (the
 * parser runs inside a read, which must not wait for room to send). */
static void send_cmd(lf_net *c, uint8_t verb, uint8_t opt)
{
    uint8_t b[3] = {LF_TN_IAC, verb, opt};
    ans_queue(c, b, sizeof b);
}

/* What we do ourselves: binary, COM-PORT-OPTION. What we want the server
 * to do: binary, suppress go-ahead. Anything else (ECHO: the server would
 * echo our frames back) is refused once. */
static int we_may(uint8_t opt) { return opt == LF_TN_OPT_BINARY || opt == LF_TN_OPT_COMPORT; }
static int he_may(uint8_t opt) { return opt == LF_TN_OPT_BINARY || opt == LF_TN_OPT_SGA; }

/* One side of an option: ours (the server sent DO/DONT) or the server's
 * (WILL/WONT). Only a change is answered, so two peers never loop. */
static void negotiate(lf_net *c, uint8_t *state, int allowed, int asked_on, uint8_t yes,
                      uint8_t no, uint8_t opt)
{
    if (asked_on && allowed) {
        if (*state != OPT_ASKED && *state != OPT_ON)
            send_cmd(c, yes, opt);
        *state = OPT_ON;
    } else if (asked_on) {
        if (*state != OPT_REFUSED)
            send_cmd(c, no, opt);
        *state = OPT_REFUSED;
    } else {
        if (*state == OPT_ON)
            send_cmd(c, no, opt);
        *state = OPT_REFUSED;
    }
}

static void on_cmd(void *ctx, uint8_t verb, uint8_t opt, const uint8_t *sb, size_t len)
{
    lf_net *c = ctx;
    switch (verb) {
    case LF_TN_DO:
    case LF_TN_DONT:
        negotiate(c, &c->us[opt], we_may(opt), verb == LF_TN_DO, LF_TN_WILL, LF_TN_WONT, opt);
        break;
    case LF_TN_WILL:
    case LF_TN_WONT:
        negotiate(c, &c->him[opt], he_may(opt), verb == LF_TN_WILL, LF_TN_DO, LF_TN_DONT, opt);
        break;
    case LF_TN_SB:
        /* COM-PORT answers: cmd + 100, then the value (1 or 4 bytes) */
        if (opt == LF_TN_OPT_COMPORT && len >= 1 && sb[0] >= LF_CPC_SERVER &&
            sb[0] < LF_CPC_SERVER + 16) {
            unsigned k = sb[0] - LF_CPC_SERVER;
            uint32_t v = 0;
            for (size_t i = 1; i < len && i <= 4; i++)
                v = (v << 8) | sb[i];
            if (c->answered[k]++ == 0)
                c->answer_val[k] = v;   /* later ones: the fence's (below) */
        }
        break;
    default:
        break;
    }
}

/* Receive what is there (one recv) and run it through the Telnet parser;
 * data bytes go to out (room for n). Same returns as recv(); only
 * commands read: -1 with EAGAIN (nothing for the caller yet). One recv per
 * call, never a loop: a server that sends nothing but commands keeps the
 * caller in its own bounded wait (deadline, cancel fd), not in here. */
static ssize_t telnet_recv(lf_net *c, int fd, uint8_t *out, size_t n)
{
    uint8_t raw[512];
    size_t want = n < sizeof raw ? n : sizeof raw;
    ssize_t r = recv(fd, raw, want, MSG_DONTWAIT);
    if (r <= 0) {
        if (r < 0)
            map_gone();
        return r;
    }
    size_t d = lf_telnet_rx(&c->tn, raw, (size_t)r, out, on_cmd, c);
    ans_flush_nowait(c, fd);
    if (d > 0)
        return (ssize_t)d;
    errno = EAGAIN;
    return -1;
}

/* Read and parse until cond(c) holds or the deadline passes (data bytes
 * read meanwhile are dropped: this runs before the port's opening flush).
 * 0, or -1 with errno (EIO: the server closed; ECANCELED). */
static int pump_until(lf_net *c, int fd, int (*cond)(const lf_net *), int64_t deadline)
{
    uint8_t junk[512];
    while (!cond(c)) {
        int w = net_wait(c, fd, POLLIN, deadline);
        if (w < 0)
            return -1;
        if (w == 0)
            return 0;
        ssize_t r = telnet_recv(c, fd, junk, sizeof junk);
        if (r == 0) {
            errno = EIO;
            return -1;
        }
        if (r < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)
            return -1;
    }
    return 0;
}

static int comport_settled(const lf_net *c)
{
    return c->us[LF_TN_OPT_COMPORT] != OPT_ASKED;
}

/* The line settings the open sends (SET-CONTROL three times). */
static const uint8_t line_cmds[] = {LF_CPC_SET_BAUDRATE, LF_CPC_SET_DATASIZE,
                                    LF_CPC_SET_PARITY, LF_CPC_SET_STOPSIZE};
static const uint8_t control_vals[] = {LF_CPC_CONTROL_NOFLOW, LF_CPC_CONTROL_DTR_ON,
                                       LF_CPC_CONTROL_RTS_ON};

/* Done when every line setting is answered and either every SET-CONTROL
 * is or the fence is: a baud query (value 0) sent last, which servers
 * answer in order, so once its answer is in no SET-CONTROL answer is
 * still on its way (ser2net on a pty never answers DTR/RTS: without the
 * fence every open would wait the whole option_ms for them). */
static int settings_answered(const lf_net *c)
{
    for (size_t i = 0; i < sizeof line_cmds; i++)
        if (!c->answered[line_cmds[i]])
            return 0;
    return c->answered[LF_CPC_SET_CONTROL] >= sizeof control_vals ||
           c->answered[LF_CPC_SET_BAUDRATE] >= 2;
}

/* ---- connect ----------------------------------------------------------- */

static void tune_socket(int fd)
{
    int one = 1, idle = KEEP_IDLE_S, intvl = KEEP_INTVL_S, cnt = KEEP_CNT;
    unsigned ut = USER_TIMEOUT_MS;
    /* best effort: a kernel without one of them still works, only slower
     * to notice a dead peer or to send a short frame */
    (void)setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    (void)setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &one, sizeof one);
    (void)setsockopt(fd, IPPROTO_TCP, TCP_KEEPIDLE, &idle, sizeof idle);
    (void)setsockopt(fd, IPPROTO_TCP, TCP_KEEPINTVL, &intvl, sizeof intvl);
    (void)setsockopt(fd, IPPROTO_TCP, TCP_KEEPCNT, &cnt, sizeof cnt);
    (void)setsockopt(fd, IPPROTO_TCP, TCP_USER_TIMEOUT, &ut, sizeof ut);
}

/* Delayed ACKs hold back a server's next segment behind Nagle (30-40 ms):
 * ACK at once. The flag does not stick, so it is set after every read. */
static void quickack(int fd)
{
    int one = 1;
    (void)setsockopt(fd, IPPROTO_TCP, TCP_QUICKACK, &one, sizeof one);
}

static int connect_one(const lf_net *c, const struct addrinfo *ai, int64_t deadline)
{
    int fd = socket(ai->ai_family, ai->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC,
                    ai->ai_protocol);
    if (fd < 0)
        return -1;
    if (connect(fd, ai->ai_addr, ai->ai_addrlen) == 0)
        return fd;
    int err = errno;
    if (err == EINPROGRESS || err == EINTR) {
        int w = net_wait(c, fd, POLLOUT, deadline);
        if (w < 0) {
            err = errno;
        } else if (w == 0) {
            err = ETIMEDOUT;
        } else {
            socklen_t len = sizeof err;
            if (getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len) < 0)
                err = errno;
            if (err == 0)
                return fd;
        }
    }
    close(fd);
    errno = err;
    return -1;
}

/* ---- name lookup: bounded by connect_ms, ended by the cancel fd ----------
 *
 * getaddrinfo() can be neither timed nor interrupted (a DNS server that
 * never answers holds it for the resolver's timeout x attempts: 10 s by
 * default). So a name (not a numeric address) is looked up by a detached
 * helper thread; the open waits for it in net_wait, bounded by the open's
 * deadline and the port's cancel fd. An open that stops waiting leaves the
 * lookup to finish on its own: the connection keeps it, and the next open
 * (a reopen) waits for that same lookup instead of starting another, so
 * one port never has more than one helper thread. The last of the thread
 * and the connection to let go frees it. */

typedef struct lf_lookup {
    pthread_mutex_t mu;
    int refs;                     /* the thread's and the connection's */
    int done;                     /* the fields below are set */
    int gai, sys_err;
    struct addrinfo *res;
    int efd;                      /* eventfd: readable once done */
    char host[sizeof ((lf_port_url *)0)->host];
    char port[sizeof ((lf_port_url *)0)->port];
} lf_lookup;

static const struct addrinfo lookup_hints = {
    .ai_family = AF_UNSPEC, .ai_socktype = SOCK_STREAM,
    .ai_flags = AI_NUMERICSERV | AI_ADDRCONFIG};

static void lookup_unref(lf_lookup *l)
{
    pthread_mutex_lock(&l->mu);
    int last = --l->refs == 0;
    pthread_mutex_unlock(&l->mu);
    if (!last)
        return;
    if (l->res)
        freeaddrinfo(l->res);
    close(l->efd);
    pthread_mutex_destroy(&l->mu);
    free(l);
}

static void *lookup_main(void *arg)
{
    lf_lookup *l = arg;
    struct addrinfo *res = NULL;
    int gai = getaddrinfo(l->host, l->port, &lookup_hints, &res);
    int err = errno;
    pthread_mutex_lock(&l->mu);
    l->gai = gai;
    l->sys_err = err;
    l->res = res;
    l->done = 1;
    uint64_t one = 1;
    if (write(l->efd, &one, sizeof one) < 0) { /* cannot fail: a fresh counter */ }
    pthread_mutex_unlock(&l->mu);
    lookup_unref(l);
    return NULL;
}

static lf_lookup *lookup_start(const lf_net *c)
{
    lf_lookup *l = calloc(1, sizeof *l);
    if (!l)
        return NULL;
    l->efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (l->efd < 0) {
        free(l);
        return NULL;
    }
    pthread_mutex_init(&l->mu, NULL);
    snprintf(l->host, sizeof l->host, "%s", c->url.host);
    snprintf(l->port, sizeof l->port, "%s", c->url.port);
    l->refs = 2;
    pthread_attr_t a;
    pthread_attr_init(&a);
    pthread_attr_setdetachstate(&a, PTHREAD_CREATE_DETACHED);
    /* no signals for the helper: SIGINT and the like stay the caller's */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    pthread_t th;
    int rc = pthread_create(&th, &a, lookup_main, l);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    pthread_attr_destroy(&a);
    if (rc != 0) {
        l->refs = 1;
        lookup_unref(l);
        errno = rc;
        return NULL;
    }
    return l;
}

/* getaddrinfo for the URL's host and port, by deadline: 0 with *res, or
 * -1 with errno (-FAP_PORT_ERESOLVE: unknown, or no answer in time;
 * ECANCELED). */
static int net_resolve(lf_net *c, struct addrinfo **res, int64_t deadline)
{
    struct addrinfo numeric = lookup_hints;
    numeric.ai_flags |= AI_NUMERICHOST;
    int gai = getaddrinfo(c->url.host, c->url.port, &numeric, res);
    if (gai == 0)
        return 0;   /* an address: no lookup, nothing to wait for */
    if (gai != EAI_NONAME) {
        errno = gai == EAI_SYSTEM ? errno : -FAP_PORT_ERESOLVE;
        return -1;
    }
    if (!c->lookup && !(c->lookup = lookup_start(c)))
        return -1;
    lf_lookup *l = c->lookup;
    int w = net_wait(c, l->efd, POLLIN, deadline);
    int werr = errno;
    pthread_mutex_lock(&l->mu);
    int done = l->done, sys_err = l->sys_err;
    if (done) {
        gai = l->gai;
        *res = l->res;
        l->res = NULL;
    }
    pthread_mutex_unlock(&l->mu);
    if (!done) {   /* still running: it stays ours for the next open */
        errno = w < 0 ? werr : -FAP_PORT_ERESOLVE;   /* ECANCELED, or no answer in time */
        return -1;
    }
    c->lookup = NULL;
    lookup_unref(l);
    if (gai != 0) {
        errno = gai == EAI_SYSTEM && sys_err ? sys_err : -FAP_PORT_ERESOLVE;
        return -1;
    }
    return 0;
}

static int net_connect(lf_net *c)
{
    /* connect_ms bounds the name lookup and the connect together */
    int64_t deadline = lf_now_ns() + (int64_t)c->url.connect_ms * LF_NS_PER_MS;
    struct addrinfo *res = NULL;
    if (net_resolve(c, &res, deadline) < 0)
        return -1;
    int fd = -1, err = ECONNREFUSED;
    for (struct addrinfo *ai = res; ai && fd < 0; ai = ai->ai_next) {
        fd = connect_one(c, ai, deadline);
        if (fd < 0)
            err = errno;
        if (fd < 0 && (err == ECANCELED || err == ETIMEDOUT))
            break;   /* stopped, or connect_ms used up */
    }
    freeaddrinfo(res);
    if (fd < 0) {
        errno = err;
        return -1;
    }
    tune_socket(fd);
    return fd;
}

/* RFC 2217: binary both ways and COM-PORT-OPTION. A server that answers
 * DONT COM-PORT-OPTION is not one (FAP_PORT_EREFUSED); nor is one that
 * sends no Telnet command at all within option_ms (EPROTO: a raw TCP
 * port, whose bus would take the negotiation as data); one that
 * negotiates but leaves COM-PORT-OPTION unanswered gets a warning and is
 * used anyway. */
static int rfc2217_start(lf_net *c, int fd)
{
    lf_telnet_init(&c->tn);
    memset(c->us, 0, sizeof c->us);
    memset(c->him, 0, sizeof c->him);
    pthread_mutex_lock(&c->ans_mu);
    c->ans_len = 0;   /* a new connection: nothing owed */
    c->answers = 0;
    pthread_mutex_unlock(&c->ans_mu);
    const uint8_t hello[] = {LF_TN_IAC, LF_TN_WILL, LF_TN_OPT_BINARY,
                             LF_TN_IAC, LF_TN_DO, LF_TN_OPT_BINARY,
                             LF_TN_IAC, LF_TN_WILL, LF_TN_OPT_COMPORT};
    c->us[LF_TN_OPT_BINARY] = c->him[LF_TN_OPT_BINARY] = OPT_ASKED;
    c->us[LF_TN_OPT_COMPORT] = OPT_ASKED;
    int64_t deadline = lf_now_ns() + (int64_t)c->url.option_ms * LF_NS_PER_MS;
    if (send_all(c, fd, hello, sizeof hello, deadline) < 0)
        return -1;
    if (pump_until(c, fd, comport_settled, deadline) < 0)
        return -1;
    if (c->us[LF_TN_OPT_COMPORT] == OPT_REFUSED) {
        errno = -FAP_PORT_EREFUSED;
        return -1;
    }
    if (c->us[LF_TN_OPT_COMPORT] == OPT_ASKED && c->tn.cmds == 0) {
        errno = EPROTO;   /* not a word of Telnet: not an RFC 2217 server */
        return -1;
    }
    if (c->us[LF_TN_OPT_COMPORT] == OPT_ASKED)
        set_warning(c, "rfc2217: no answer to WILL COM-PORT-OPTION; continuing");
    return 0;
}

/* ---- the transport table ------------------------------------------------- */

static int net_open(void *ctx, const char *path)
{
    (void)path;   /* parsed into ctx by the transport map (lf_port_net_prepare) */
    lf_net *c = ctx;
    set_warning(c, "");   /* a new connection: earlier notes are stale */
    int fd = net_connect(c);
    if (fd < 0)
        return -errno;
    c->fd = fd;
    if (c->url.scheme == LF_PORT_RFC2217 && rfc2217_start(c, fd) < 0) {
        int err = errno;
        close(fd);
        c->fd = -1;
        return -err;
    }
    return fd;
}

static int net_close(void *ctx, int fd)
{
    lf_net *c = ctx;
    if (c->fd == fd)
        c->fd = -1;
    return close(fd);
}

/* The line settings, 8N1 at baud: stored (raw TCP: the server's own are in
 * force); on RFC 2217 sent to the server, and its answers checked. 0, or -1
 * with errno. */
static int send_line_settings(lf_net *c, int fd, uint32_t baud)
{
    c->baud = baud;
    if (c->url.scheme != LF_PORT_RFC2217)
        return 0;
    uint32_t want[16] = {0};
    want[LF_CPC_SET_BAUDRATE] = baud;
    want[LF_CPC_SET_DATASIZE] = 8;
    want[LF_CPC_SET_PARITY] = LF_CPC_PARITY_NONE;
    want[LF_CPC_SET_STOPSIZE] = LF_CPC_STOP_1;
    uint8_t msg[16 * (2 + sizeof line_cmds + sizeof control_vals)];
    size_t len = 0;
    memset(c->answered, 0, sizeof c->answered);
    /* Purge first: the server works in order, so once the settings are
     * answered the purge is done, and no byte that arrives after the open
     * is purged late (ser2net never answers PURGE-DATA itself). */
    const uint8_t both = LF_CPC_PURGE_BOTH;
    len += lf_telnet_cpc(LF_CPC_PURGE_DATA, &both, 1, msg + len);
    c->purged = 1;
    const uint8_t be32[4] = {(uint8_t)(baud >> 24), (uint8_t)(baud >> 16),
                             (uint8_t)(baud >> 8), (uint8_t)baud};
    for (size_t i = 0; i < sizeof line_cmds; i++) {
        uint8_t cmd = line_cmds[i];
        if (cmd == LF_CPC_SET_BAUDRATE)
            len += lf_telnet_cpc(cmd, be32, 4, msg + len);
        else
            len += lf_telnet_cpc(cmd, (const uint8_t[]){(uint8_t)want[cmd]}, 1, msg + len);
    }
    for (size_t i = 0; i < sizeof control_vals; i++)
        len += lf_telnet_cpc(LF_CPC_SET_CONTROL, &control_vals[i], 1, msg + len);
    const uint8_t query[4] = {0, 0, 0, 0};   /* the fence: "which baud now?" */
    len += lf_telnet_cpc(LF_CPC_SET_BAUDRATE, query, 4, msg + len);
    int64_t deadline = lf_now_ns() + (int64_t)c->url.option_ms * LF_NS_PER_MS;
    if (send_all(c, fd, msg, len, deadline) < 0)
        return -1;
    if (pump_until(c, fd, settings_answered, deadline) < 0)
        return -1;
    /* A line setting answered with another value: the server cannot do
     * 8N1 at this baud, and frames would be garbage: an error. Unanswered:
     * some servers never answer; a warning. Control lines (flow off,
     * DTR/RTS on) never fail an open: ser2net on a pty never answers. */
    char note[200] = "";
    for (size_t i = 0; i < sizeof line_cmds; i++) {
        uint8_t cmd = line_cmds[i];
        if (c->answered[cmd] && c->answer_val[cmd] != want[cmd]) {
            set_warning(c, cmd == LF_CPC_SET_BAUDRATE
                               ? "rfc2217: the server refused the baud rate"
                               : "rfc2217: the server refused 8 data bits, no parity, 1 stop bit");
            errno = -FAP_PORT_EREFUSED;
            return -1;
        }
        if (!c->answered[cmd] && !note[0])
            snprintf(note, sizeof note, "rfc2217: no answer to a line setting within %u ms; "
                     "continuing", c->url.option_ms);
    }
    if (!note[0] && c->answered[LF_CPC_SET_CONTROL] < sizeof control_vals) {
        if (c->answered[LF_CPC_SET_BAUDRATE] >= 2)   /* fence answered: it never will */
            snprintf(note, sizeof note, "rfc2217: the server does not answer SET-CONTROL "
                     "(flow off, DTR on, RTS on); continuing");
        else
            snprintf(note, sizeof note, "rfc2217: the server did not answer every SET-CONTROL "
                     "(flow off, DTR on, RTS on) within %u ms; continuing", c->url.option_ms);
    }
    if (note[0])
        set_warning(c, note);
    return 0;
}

static int net_set_line(void *ctx, int fd, unsigned baud, int hold_rts)
{
    (void)hold_rts;   /* never asked: the open refuses soft RTS (lf_port_net_prepare) */
    return send_line_settings(ctx, fd, baud) < 0 ? -errno : 0;
}

/* Read the socket empty (bounded); RFC 2217 also purges the server's
 * buffers, without waiting for its answer (the parser takes it later).
 * 0, or -1 with errno. */
static int purge(void *ctx, int fd, int queue)
{
    lf_net *c = ctx;
    int purged = c->purged;   /* the open's flush: set_line purged in order */
    c->purged = 0;
    if (c->url.scheme == LF_PORT_RFC2217 && !purged) {
        uint8_t what = queue == LF_PORT_FLUSH_IN ? LF_CPC_PURGE_RX
                       : queue == LF_PORT_FLUSH_OUT ? LF_CPC_PURGE_TX : LF_CPC_PURGE_BOTH;
        uint8_t msg[16];
        if (send_all(c, fd, msg, lf_telnet_cpc(LF_CPC_PURGE_DATA, &what, 1, msg),
                     send_deadline()) < 0)
            return -1;
    }
    if (queue == LF_PORT_FLUSH_OUT)
        return 0;
    uint8_t junk[512];
    for (int i = 0; i < 64; i++) {
        ssize_t r = c->url.scheme == LF_PORT_RFC2217 ? telnet_recv(c, fd, junk, sizeof junk)
                                                     : recv(fd, junk, sizeof junk, MSG_DONTWAIT);
        if (r == 0) {
            errno = EIO;
            return -1;
        }
        if (r < 0) {
            if (errno == EAGAIN || errno == EWOULDBLOCK)
                return 0;
            map_gone();
            return -1;
        }
    }
    return 0;
}

static int net_flush(void *ctx, int fd, int queue)
{
    return purge(ctx, fd, queue) < 0 ? -errno : 0;
}

static int net_drain(void *ctx, int fd)
{
    (void)ctx;
    (void)fd;
    return 0;   /* the bytes are the server's once sent; no way to see its UART */
}

static ssize_t net_read(void *ctx, int fd, void *buf, size_t n)
{
    lf_net *c = ctx;
    ssize_t r = c->url.scheme == LF_PORT_RFC2217 ? telnet_recv(c, fd, buf, n)
                                                 : recv(fd, buf, n, MSG_DONTWAIT);
    if (r > 0)
        quickack(fd);
    else if (r < 0)
        map_gone();
    return r;
}

static ssize_t net_write(void *ctx, int fd, const void *buf, size_t n)
{
    lf_net *c = ctx;
    if (c->url.scheme != LF_PORT_RFC2217) {
        ssize_t w = send(fd, buf, n, MSG_NOSIGNAL | MSG_DONTWAIT);
        if (w < 0)
            map_gone();
        return w;
    }
    /* escaped, one chunk per call: the port layer loops over the rest */
    uint8_t enc[2 * 1024];
    size_t take = n < sizeof enc / 2 ? n : sizeof enc / 2;
    size_t len = lf_telnet_escape(buf, take, enc);
    if (send_all(c, fd, enc, len, send_deadline()) < 0)
        return -1;   /* ECANCELED: a close ends a send to a server that does not read */
    return (ssize_t)take;
}


static void net_destroy(void *ctx)
{
    lf_net *c = ctx;
    if (c->lookup)
        lookup_unref(c->lookup);   /* still running: the thread frees it */
    pthread_mutex_destroy(&c->tx_mu);
    pthread_mutex_destroy(&c->st_mu);
    pthread_mutex_destroy(&c->ans_mu);
    free(c);
}

static void net_attach(void *ctx, const int *const *cancel_fd)
{
    ((lf_net *)ctx)->cancel = cancel_fd;
}

static int64_t net_slack_ns(void *ctx)
{
    return (int64_t)((const lf_net *)ctx)->url.rtt_ms * LF_NS_PER_MS;
}

static size_t net_warning(void *ctx, char *buf, size_t n)
{
    lf_net *c = ctx;
    pthread_mutex_lock(&c->st_mu);
    size_t len = strlen(c->warning);
    if (buf && n)
        snprintf(buf, n, "%s", c->warning);
    pthread_mutex_unlock(&c->st_mu);
    return len;
}

/* No rs485, rts, lock, unlock, tx_empty, restore_line or GPIO: see the top. */
static const lf_port_transport net_transport = {
    .open = net_open,
    .close = net_close,
    .set_line = net_set_line,
    .flush = net_flush,
    .drain = net_drain,
    .read = net_read,
    .write = net_write,
    .poll = lf_port_posix_poll,
    .sleep_until = lf_port_posix_sleep_until,
    .destroy = net_destroy,
    .attach = net_attach,
    .caps = FAP_PORT_CAP_NETWORK,
    .slack_ns = net_slack_ns,
    .warning = net_warning,
};

int lf_port_net_prepare(const lf_port_url *u, const fap_port_options *o,
                        const lf_port_transport **tr, void **ctx)
{
    if (!u || !tr || !ctx)
        return -EINVAL;
    if (o && (o->rs485_mode == FAP_RS485_KERNEL || o->rs485_mode == FAP_RS485_SOFT_RTS
              || o->rs485_mode == FAP_RS485_GPIO))
        return FAP_PORT_ENET485;
    lf_net *c = calloc(1, sizeof *c);
    if (!c)
        return -ENOMEM;
    c->url = *u;
    c->fd = -1;
    pthread_mutex_init(&c->tx_mu, NULL);
    pthread_mutex_init(&c->st_mu, NULL);
    pthread_mutex_init(&c->ans_mu, NULL);
    *tr = &net_transport;
    *ctx = c;
    return 0;
}
