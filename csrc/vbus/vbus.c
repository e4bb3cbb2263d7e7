/* vbus.c - the virtual RS-485 bus: ptys, symlinks and the relay thread.
 *
 * One relay thread polls every pty master, an inotify fd (nodes opening
 * and closing the ports), an eventfd (wake-ups from the control calls and
 * close) and a timerfd (absolute CLOCK_MONOTONIC: paced deliveries,
 * reconnects, capture lines). It never busy-loops. What each
 * port receives is decided by the sans-I/O wire model (vbus_wire.c); this
 * file only moves bytes between fds and that model.
 *
 * Locking: one mutex guards everything; the relay holds it except while in
 * poll(). Control calls take it briefly; disconnect waits for the relay to
 * have closed the pty (fds are only ever closed by the relay thread, never
 * under a poll() in progress).
 */
#include "fap_vbus.h"
#include "common/mono_timerfd.h"
#include "vbus/vbus_capture.h"
#include "vbus/vbus_pty.h"
#include "vbus/vbus_wire.h"

#include <errno.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <sys/eventfd.h>
#include <sys/ioctl.h>
#include <sys/inotify.h>
#include <sys/stat.h>
#include <sys/timerfd.h>
#include <unistd.h>

/* Bytes queued for a node that does not keep up; beyond that, drop and
 * count (stats.overflow) rather than stall the whole bus. */
#define LF_VBUS_OUTQ_CAP (64 * 1024)
#define LF_VBUS_READ_CHUNK (64 * 1024)
#define LF_VBUS_MAX_BAUD 10000000u
#define LF_VBUS_RECONNECT_RETRY_NS (100 * LF_NS_PER_MS)

typedef struct vbus_port {
    lf_pty pty;               /* fds are -1 while disconnected */
    char *link;               /* the stable path handed to users */
    uint8_t *outq;            /* ring of LF_VBUS_OUTQ_CAP bytes for this node */
    size_t oq_head, oq_len;
    int attached;             /* nodes that have the slave open (inotify) */
    lf_ns reconnect_at;       /* LF_NEVER while connected */
    int disconnect_req;       /* a control call asked for a disconnect... */
    unsigned disconnect_ms;   /* ...of this long */
} vbus_port;

struct fap_vbus {
    unsigned n_ports;
    char *dir;
    int own_dir;              /* we created dir: remove it at close */
    vbus_port port[FAP_VBUS_MAX_PORTS];
    lf_wire wire;
    lf_capture cap;
    int evfd, tfd;
    int infd;                 /* inotify: nodes opening/closing the slaves */
    int tracking;             /* attach tracking works (else: all attached) */
    lf_ns timer_armed;        /* LF_NEVER = disarmed */
    uint8_t *rbuf;

    pthread_t thread;
    int thread_started;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    int closing;
    uint64_t req_gen, done_gen;
    fap_port_rt rt;           /* real-time option: the relay applies it, open waits */
    int rt_err, rt_known;

    uint64_t bytes_out, overflow, disconnects;

    pid_t owner;              /* the process that opened it (not a fork child) */
    struct fap_vbus *live_next;
};

/* ---- output queues --------------------------------------------------- */

static void outq_push(fap_vbus *b, vbus_port *pt, const uint8_t *d, size_t n)
{
    size_t room = LF_VBUS_OUTQ_CAP - pt->oq_len;
    if (n > room) {
        b->overflow += n - room;
        lf_capture_event(&b->cap, lf_now_ns(), "overflow", "port=%u n=%zu",
                         (unsigned)(pt - b->port), n - room);
        n = room;
    }
    size_t tail = (pt->oq_head + pt->oq_len) % LF_VBUS_OUTQ_CAP;
    size_t first = LF_VBUS_OUTQ_CAP - tail < n ? LF_VBUS_OUTQ_CAP - tail : n;
    memcpy(pt->outq + tail, d, first);
    memcpy(pt->outq, d + first, n - first);
    pt->oq_len += n;
}

/* Write as much of the queue as the master takes. */
static void outq_flush(fap_vbus *b, vbus_port *pt)
{
    while (pt->oq_len && pt->pty.master >= 0) {
        size_t chunk = LF_VBUS_OUTQ_CAP - pt->oq_head;
        if (chunk > pt->oq_len)
            chunk = pt->oq_len;
        ssize_t w = write(pt->pty.master, pt->outq + pt->oq_head, chunk);
        if (w <= 0)
            return;   /* EAGAIN: POLLOUT will call again */
        b->bytes_out += (uint64_t)w;
        pt->oq_head = (pt->oq_head + (size_t)w) % LF_VBUS_OUTQ_CAP;
        pt->oq_len -= (size_t)w;
    }
    if (!pt->oq_len)
        pt->oq_head = 0;
}

static void port_write(fap_vbus *b, vbus_port *pt, const uint8_t *d, size_t n)
{
    if (pt->pty.master < 0)
        return;
    if (b->tracking && !pt->attached)
        return;   /* nobody listens: like a serial line with no device open */
    if (!pt->oq_len) {
        ssize_t w = write(pt->pty.master, d, n);
        if (w > 0) {
            b->bytes_out += (uint64_t)w;
            d += w;
            n -= (size_t)w;
        }
    }
    if (n)
        outq_push(b, pt, d, n);
}

/* ---- attach tracking ----------------------------------------------------
 * A port nobody has open receives nothing (else bytes would pile up in the
 * pty and in our queue and greet the next opener, even after its tcflush).
 * The relay drains these events before every delivery decision, so an
 * open that happened before a byte was read is always known. */

static void outq_discard(vbus_port *pt)
{
    pt->oq_head = pt->oq_len = 0;
}

static void attach_events(fap_vbus *b)
{
    union {
        struct inotify_event ev;
        char raw[4096];
    } buf;
    while (b->tracking) {
        ssize_t r = read(b->infd, buf.raw, sizeof buf.raw);
        if (r <= 0)
            return;   /* EAGAIN: all caught up */
        for (char *p = buf.raw; p < buf.raw + r;) {
            struct inotify_event *e = (struct inotify_event *)(void *)p;
            p += sizeof *e + e->len;
            if (e->mask & IN_Q_OVERFLOW) {
                b->tracking = 0;   /* lost count: treat every port as attached */
                return;
            }
            for (unsigned i = 0; i < b->n_ports; i++) {
                vbus_port *pt = &b->port[i];
                if (pt->pty.wd != e->wd || pt->pty.master < 0)
                    continue;
                if (e->mask & IN_OPEN) {
                    if (pt->attached++ == 0) {
                        /* a fresh node: nothing left over from the last one */
                        outq_discard(pt);
                        tcflush(pt->pty.slave, TCIFLUSH);
                    }
                } else if (e->mask & IN_CLOSE) {
                    if (pt->attached > 0 && --pt->attached == 0) {
                        /* the last node left: what it did not read is stale,
                         * and a TIOCEXCL it set (and maybe died with) would
                         * lock out the next one, since we keep the tty open */
                        outq_discard(pt);
                        tcflush(pt->pty.slave, TCIFLUSH);
                        ioctl(pt->pty.slave, TIOCNXCL);
                    }
                }
            }
        }
    }
}

/* Start watching a new pty (before its path is published). */
static void port_watch(fap_vbus *b, vbus_port *pt)
{
    pt->attached = 0;
    if (b->tracking && lf_pty_watch(b->infd, &pt->pty) != 0)
        b->tracking = 0;   /* out of inotify watches: fall back to "all attached" */
}

/* ---- wire model sink (called with the mutex held) --------------------- */

static void sink_deliver(void *ctx, unsigned sender, uint64_t to, const uint8_t *data,
                         size_t n, lf_ns t)
{
    fap_vbus *b = ctx;
    lf_capture_data(&b->cap, t, sender, data, n);
    for (unsigned q = 0; q < b->n_ports; q++)
        if (to & (1ull << q))
            port_write(b, &b->port[q], data, n);
}

static void sink_collision(void *ctx, unsigned a, unsigned c, lf_ns t)
{
    fap_vbus *b = ctx;
    lf_capture_event(&b->cap, t, "collision", "ports=%u,%u", a < c ? a : c, a < c ? c : a);
}

static void sink_fault(void *ctx, unsigned port, lf_wire_reason r, size_t n, lf_ns t)
{
    fap_vbus *b = ctx;
    lf_capture_event(&b->cap, t, "fault", "port=%u reason=%s n=%zu", port,
                     lf_wire_reason_name(r), n);
}

/* ---- disconnect / reconnect (relay thread only) ----------------------- */

static void port_disconnect(fap_vbus *b, unsigned i, unsigned ms, lf_ns now)
{
    vbus_port *pt = &b->port[i];
    if (pt->pty.master >= 0) {
        /* Re-point the path at a name that does not exist first, so a node
         * that reopens meanwhile gets ENOENT, never a recycled /dev/pts/N. */
        char gone[32];
        snprintf(gone, sizeof gone, ".port%u.disconnected", i);
        lf_symlink_replace(pt->link, gone);
        attach_events(b);
        lf_pty_unwatch(b->infd, &pt->pty);
        lf_pty_close(&pt->pty);   /* the node's fd hangs up: EIO */
        pt->attached = 0;
        outq_discard(pt);
        lf_wire_set_connected(&b->wire, i, 0);
        b->disconnects++;
    }
    pt->reconnect_at = now + (lf_ns)ms * LF_NS_PER_MS;
    lf_capture_event(&b->cap, now, "disconnect", "port=%u ms=%u", i, ms);
}

static void port_reconnect(fap_vbus *b, unsigned i, lf_ns now)
{
    vbus_port *pt = &b->port[i];
    int err = lf_pty_open(&pt->pty);
    if (!err) {
        port_watch(b, pt);
        err = lf_symlink_replace(pt->link, pt->pty.name);
    }
    if (err) {
        lf_pty_unwatch(b->infd, &pt->pty);
        lf_pty_close(&pt->pty);
        pt->reconnect_at = now + LF_VBUS_RECONNECT_RETRY_NS;   /* fd shortage: retry */
        return;
    }
    pt->reconnect_at = LF_NEVER;
    lf_wire_set_connected(&b->wire, i, 1);
    lf_capture_event(&b->cap, now, "reconnect", "port=%u", i);
}

/* ---- relay thread ------------------------------------------------------ */

static void arm_timer(fap_vbus *b, lf_ns deadline)
{
    if (deadline == b->timer_armed)
        return;
    lf_timerfd_arm_at(b->tfd, deadline);
    b->timer_armed = deadline;
}

static void drain_fd(int fd)
{
    uint64_t v;
    while (read(fd, &v, sizeof v) == (ssize_t)sizeof v)
        ;
}

/* Everything that is due at `now`; returns the next deadline. */
static lf_ns relay_due(fap_vbus *b, lf_ns now)
{
    if (b->req_gen != b->done_gen) {
        for (unsigned i = 0; i < b->n_ports; i++) {
            if (b->port[i].disconnect_req) {
                b->port[i].disconnect_req = 0;
                port_disconnect(b, i, b->port[i].disconnect_ms, now);
            }
        }
        b->done_gen = b->req_gen;
        pthread_cond_broadcast(&b->cv);
    }
    lf_ns next = LF_NEVER;
    for (unsigned i = 0; i < b->n_ports; i++) {
        if (b->port[i].reconnect_at <= now)
            port_reconnect(b, i, now);
        if (b->port[i].reconnect_at < next)
            next = b->port[i].reconnect_at;
    }
    attach_events(b);
    lf_wire_advance(&b->wire, now);
    lf_ns due = lf_wire_next_due(&b->wire);
    if (due < next)
        next = due;
    lf_capture_tick(&b->cap, now);
    due = lf_capture_due(&b->cap);
    return due < next ? due : next;
}

static void *relay_main(void *arg)
{
    fap_vbus *b = arg;
    struct pollfd pfd[3 + FAP_VBUS_MAX_PORTS];
    int who[3 + FAP_VBUS_MAX_PORTS];

    int rt = fap_port_rt_apply(&b->rt);   /* real-time option (port_rt.c) */
    pthread_mutex_lock(&b->mu);
    b->rt_err = rt;
    b->rt_known = 1;
    b->closing |= rt != 0;   /* refused: fap_vbus_open fails with rt */
    pthread_cond_broadcast(&b->cv);
    for (;;) {
        lf_ns next = relay_due(b, lf_now_ns());
        if (b->closing)
            break;
        arm_timer(b, next);
        nfds_t nfds = 0;
        pfd[nfds] = (struct pollfd){ .fd = b->evfd, .events = POLLIN };
        who[nfds++] = -1;
        pfd[nfds] = (struct pollfd){ .fd = b->tfd, .events = POLLIN };
        who[nfds++] = -2;
        if (b->tracking) {   /* opens/closes: handled by relay_due() */
            pfd[nfds] = (struct pollfd){ .fd = b->infd, .events = POLLIN };
            who[nfds++] = -3;
        }
        for (unsigned i = 0; i < b->n_ports; i++) {
            vbus_port *pt = &b->port[i];
            if (pt->pty.master < 0)
                continue;
            short ev = 0;
            if (lf_wire_space(&b->wire, i))
                ev |= POLLIN;   /* paced and full: leave it to the node's tx buffer */
            if (pt->oq_len)
                ev |= POLLOUT;
            pfd[nfds] = (struct pollfd){ .fd = pt->pty.master, .events = ev };
            who[nfds++] = (int)i;
        }
        pthread_mutex_unlock(&b->mu);
        int r = poll(pfd, nfds, -1);
        pthread_mutex_lock(&b->mu);
        if (r < 0)
            continue;   /* EINTR */
        lf_ns now = lf_now_ns();
        for (nfds_t k = 0; k < nfds; k++) {
            if (!pfd[k].revents)
                continue;
            if (who[k] == -1) {
                drain_fd(b->evfd);
                continue;
            }
            if (who[k] == -2) {
                drain_fd(b->tfd);
                b->timer_armed = LF_NEVER;   /* a one-shot timer that fired is disarmed */
                continue;
            }
            if (who[k] == -3)
                continue;
            vbus_port *pt = &b->port[who[k]];
            if (pt->pty.master != pfd[k].fd)
                continue;
            if (pfd[k].revents & (POLLIN | POLLHUP | POLLERR)) {
                size_t space = lf_wire_space(&b->wire, (unsigned)who[k]);
                size_t want = space < LF_VBUS_READ_CHUNK ? space : LF_VBUS_READ_CHUNK;
                ssize_t got = want ? read(pt->pty.master, b->rbuf, want) : 0;
                if (got > 0) {
                    attach_events(b);   /* opens that came before these bytes */
                    lf_wire_send(&b->wire, (unsigned)who[k], b->rbuf, (size_t)got, now);
                } else if (want && (pfd[k].revents & (POLLHUP | POLLERR)) &&
                           (got == 0 || (errno != EAGAIN && errno != EINTR))) {
                    /* a broken pty would wake us forever: replace it, as a
                     * disconnect of 0 ms (never seen with our slave fd open) */
                    port_disconnect(b, (unsigned)who[k], 0, now);
                    continue;
                }
            }
            if (pfd[k].revents & POLLOUT)
                outq_flush(b, pt);
        }
    }
    pthread_mutex_unlock(&b->mu);
    return NULL;
}

/* ---- links of buses still open at exit ------------------------------------
 * A program that exits without fap_vbus_close (a failed test, exit() from
 * a CLI) would leave its symlinks and temp dir behind. An atexit handler
 * removes those of the buses this process opened; fork children leave
 * their parent's alone. Only paths are touched: no threads, no fds. */

static pthread_mutex_t live_mu = PTHREAD_MUTEX_INITIALIZER;
static fap_vbus *live_head;
static pthread_once_t live_once = PTHREAD_ONCE_INIT;

static void remove_links(fap_vbus *b)
{
    for (unsigned i = 0; i < FAP_VBUS_MAX_PORTS; i++)
        if (b->port[i].link)
            unlink(b->port[i].link);
    if (b->own_dir && b->dir)
        rmdir(b->dir);
}

static void live_atexit(void)
{
    /* trylock: a fork child may have inherited the lock held by a thread
     * that no longer exists; then leave the cleanup to the parent */
    if (pthread_mutex_trylock(&live_mu) != 0)
        return;
    for (fap_vbus *b = live_head; b; b = b->live_next)
        if (b->owner == getpid())
            remove_links(b);
    pthread_mutex_unlock(&live_mu);
}

static void live_init(void)
{
    atexit(live_atexit);
}

static void live_add(fap_vbus *b)
{
    pthread_once(&live_once, live_init);
    pthread_mutex_lock(&live_mu);
    b->live_next = live_head;
    live_head = b;
    pthread_mutex_unlock(&live_mu);
}

static void live_remove(fap_vbus *b)
{
    pthread_mutex_lock(&live_mu);
    for (fap_vbus **pp = &live_head; *pp; pp = &(*pp)->live_next) {
        if (*pp == b) {
            *pp = b->live_next;
            break;
        }
    }
    pthread_mutex_unlock(&live_mu);
}

/* ---- public API --------------------------------------------------------- */

void fap_vbus_options_init(fap_vbus_options *o)
{
    if (!o)
        return;
    memset(o, 0, sizeof *o);
    o->n_ports = 2;
}

static void wake(fap_vbus *b)
{
    uint64_t one = 1;
    ssize_t w = write(b->evfd, &one, sizeof one);
    (void)w;   /* EAGAIN only when the counter is already huge: still awake */
}

static void bus_destroy(fap_vbus *b)
{
    remove_links(b);
    for (unsigned i = 0; i < FAP_VBUS_MAX_PORTS; i++) {
        vbus_port *pt = &b->port[i];
        lf_pty_close(&pt->pty);
        free(pt->link);
        free(pt->outq);
    }
    free(b->dir);
    lf_wire_free(&b->wire);
    lf_capture_close(&b->cap);
    if (b->evfd >= 0)
        close(b->evfd);
    if (b->tfd >= 0)
        close(b->tfd);
    if (b->infd >= 0)
        close(b->infd);
    free(b->rbuf);
    pthread_cond_destroy(&b->cv);
    pthread_mutex_destroy(&b->mu);
    free(b);
}

static int make_dir(fap_vbus *b, const char *link_dir)
{
    if (link_dir) {
        if (!*link_dir)
            return -EINVAL;
        b->dir = strdup(link_dir);
        if (!b->dir)
            return -ENOMEM;
        if (mkdir(link_dir, 0755) == 0)
            b->own_dir = 1;
        else if (errno != EEXIST)
            return -errno;
        return 0;
    }
    const char *tmp = getenv("TMPDIR");
    if (asprintf(&b->dir, "%s/fap-vbus-XXXXXX", tmp && *tmp ? tmp : "/tmp") < 0) {
        b->dir = NULL;
        return -ENOMEM;
    }
    if (!mkdtemp(b->dir))
        return -errno;
    b->own_dir = 1;
    return 0;
}

int fap_vbus_open(fap_vbus **out, const fap_vbus_options *o)
{
    if (!out || !o || o->n_ports < 2 || o->n_ports > FAP_VBUS_MAX_PORTS ||
        o->baud > LF_VBUS_MAX_BAUD)
        return -EINVAL;
    *out = NULL;
    fap_vbus *b = calloc(1, sizeof *b);
    if (!b)
        return -ENOMEM;
    b->evfd = b->tfd = b->infd = -1;
    for (unsigned i = 0; i < FAP_VBUS_MAX_PORTS; i++) {
        b->port[i].pty.master = b->port[i].pty.slave = b->port[i].pty.wd = -1;
        b->port[i].reconnect_at = LF_NEVER;
    }
    b->cap.dirty_since = LF_NEVER;
    pthread_mutex_init(&b->mu, NULL);
    pthread_cond_init(&b->cv, NULL);
    b->n_ports = o->n_ports;
    b->timer_armed = LF_NEVER;
    lf_ns t0 = lf_now_ns();   /* capture times count from here */

    lf_wire_sink sink = { .ctx = b, .deliver = sink_deliver, .collision = sink_collision,
                          .fault = sink_fault };
    int err = lf_wire_init(&b->wire, o->n_ports, o->baud, o->echo, o->seed, &sink);
    if (err)
        goto fail;
    err = make_dir(b, o->link_dir);
    if (err)
        goto fail;
    /* no inotify (instance limit reached): every port counts as attached */
    b->infd = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
    b->tracking = b->infd >= 0;
    for (unsigned i = 0; i < b->n_ports; i++) {
        vbus_port *pt = &b->port[i];
        pt->outq = malloc(LF_VBUS_OUTQ_CAP);
        if (!pt->outq || asprintf(&pt->link, "%s/port%u", b->dir, i) < 0) {
            pt->link = NULL;
            err = -ENOMEM;
            goto fail;
        }
        struct stat st;
        if (lstat(pt->link, &st) == 0 && !S_ISLNK(st.st_mode)) {
            /* a user's file, not a link we left behind: never clobber it */
            free(pt->link);
            pt->link = NULL;
            err = -EEXIST;
            goto fail;
        }
        err = lf_pty_open(&pt->pty);
        if (!err) {
            port_watch(b, pt);
            err = lf_symlink_replace(pt->link, pt->pty.name);
        }
        if (err)
            goto fail;
    }
    if (o->capture_path) {
        err = lf_capture_open(&b->cap, o->capture_path, t0, o->n_ports, o->baud,
                              o->echo, o->seed);
        if (err)
            goto fail;
    }
    b->rbuf = malloc(LF_VBUS_READ_CHUNK);
    b->evfd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    b->tfd = timerfd_create(CLOCK_MONOTONIC, TFD_CLOEXEC | TFD_NONBLOCK);
    if (!b->rbuf || b->evfd < 0 || b->tfd < 0) {
        err = b->rbuf ? -errno : -ENOMEM;
        goto fail;
    }
    /* The relay takes no signals: the application's handlers run in its
     * own threads, and our syscalls see no EINTR. */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    b->rt = o->rt;
    err = -pthread_create(&b->thread, NULL, relay_main, b);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (err)
        goto fail;
    pthread_mutex_lock(&b->mu);   /* the relay's real-time settings took, or not */
    while (!b->rt_known)
        pthread_cond_wait(&b->cv, &b->mu);
    err = b->rt_err;
    pthread_mutex_unlock(&b->mu);
    if (err) {
        pthread_join(b->thread, NULL);
        goto fail;
    }
    pthread_setname_np(b->thread, "fap-vbus");   /* for top -H, gdb */
    b->thread_started = 1;
    b->owner = getpid();
    live_add(b);
    *out = b;
    return 0;
fail:
    bus_destroy(b);
    return err;
}

void fap_vbus_close(fap_vbus *b)
{
    if (!b)
        return;
    pthread_mutex_lock(&b->mu);
    b->closing = 1;
    pthread_cond_broadcast(&b->cv);
    pthread_mutex_unlock(&b->mu);
    wake(b);
    live_remove(b);
    if (b->thread_started)
        pthread_join(b->thread, NULL);
    /* the relay is gone: no lock needed from here on */
    lf_capture_event(&b->cap, lf_now_ns(), "end",
                     "bytes_in=%llu bytes_out=%llu collisions=%llu bit_errors=%llu "
                     "dropped=%llu overflow=%llu",
                     (unsigned long long)b->wire.stats.bytes_in,
                     (unsigned long long)b->bytes_out,
                     (unsigned long long)b->wire.stats.collisions,
                     (unsigned long long)b->wire.stats.bit_errors,
                     (unsigned long long)b->wire.stats.dropped,
                     (unsigned long long)b->overflow);
    bus_destroy(b);
}

unsigned fap_vbus_port_count(const fap_vbus *b)
{
    return b ? b->n_ports : 0;
}

const char *fap_vbus_port_path(const fap_vbus *b, unsigned i)
{
    if (!b || i >= b->n_ports)
        return NULL;
    return b->port[i].link;   /* set once at open, never changed */
}

static int valid_rate(double r)
{
    return !isnan(r) && r >= 0.0 && r <= 1.0;
}

int fap_vbus_set_fault(fap_vbus *b, int port, double bit_error_rate, double drop_rate)
{
    if (!b || port < -1 || (port >= 0 && (unsigned)port >= b->n_ports) ||
        !valid_rate(bit_error_rate) || !valid_rate(drop_rate))
        return -EINVAL;
    pthread_mutex_lock(&b->mu);
    for (unsigned i = 0; i < b->n_ports; i++)
        if (port < 0 || (unsigned)port == i)
            lf_wire_set_rates(&b->wire, i, bit_error_rate, drop_rate);
    pthread_mutex_unlock(&b->mu);
    return 0;
}

int fap_vbus_drop_next(fap_vbus *b, unsigned port, unsigned n)
{
    if (!b || port >= b->n_ports)
        return -EINVAL;
    pthread_mutex_lock(&b->mu);
    lf_wire_drop_next(&b->wire, port, n);
    pthread_mutex_unlock(&b->mu);
    return 0;
}

int fap_vbus_corrupt_next(fap_vbus *b, unsigned port, unsigned n)
{
    if (!b || port >= b->n_ports)
        return -EINVAL;
    pthread_mutex_lock(&b->mu);
    lf_wire_corrupt_next(&b->wire, port, n);
    pthread_mutex_unlock(&b->mu);
    return 0;
}

int fap_vbus_silence(fap_vbus *b, unsigned port, unsigned ms)
{
    if (!b || port >= b->n_ports)
        return -EINVAL;
    pthread_mutex_lock(&b->mu);
    lf_ns now = lf_now_ns();
    lf_wire_silence(&b->wire, port, now + (lf_ns)ms * LF_NS_PER_MS);
    lf_capture_event(&b->cap, now, "silence", "port=%u ms=%u", port, ms);
    pthread_mutex_unlock(&b->mu);
    return 0;
}

int fap_vbus_disconnect(fap_vbus *b, unsigned port, unsigned ms)
{
    if (!b || port >= b->n_ports)
        return -EINVAL;
    pthread_mutex_lock(&b->mu);
    if (b->closing) {
        pthread_mutex_unlock(&b->mu);
        return -ESHUTDOWN;
    }
    b->port[port].disconnect_req = 1;
    b->port[port].disconnect_ms = ms;
    uint64_t gen = ++b->req_gen;
    wake(b);
    /* returns once the pty is closed: the node sees the hangup from now on */
    while (b->done_gen < gen && !b->closing)
        pthread_cond_wait(&b->cv, &b->mu);
    pthread_mutex_unlock(&b->mu);
    return 0;
}

void fap_vbus_get_stats(const fap_vbus *cb, fap_vbus_stats *out)
{
    if (!out)
        return;
    memset(out, 0, sizeof *out);
    if (!cb)
        return;
    fap_vbus *b = (fap_vbus *)cb;   /* the mutex is not part of the logical state */
    pthread_mutex_lock(&b->mu);
    out->bytes_in = b->wire.stats.bytes_in;
    out->bytes_out = b->bytes_out;
    out->collisions = b->wire.stats.collisions;
    out->bit_errors = b->wire.stats.bit_errors;
    out->dropped = b->wire.stats.dropped;
    out->overflow = b->overflow;
    out->disconnects = b->disconnects;
    out->paced_bytes = b->wire.stats.paced_bytes;
    out->pace_late_sum_ns = b->wire.stats.late_sum_ns;
    out->pace_late_max_ns = b->wire.stats.late_max_ns;
    pthread_mutex_unlock(&b->mu);
}
