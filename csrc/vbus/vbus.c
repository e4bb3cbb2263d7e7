/* vbus.c - the virtual RS-485 bus's public API (fap_vbus.h): open and
 * close, fault controls, stats. The ports, the relay thread and the links
 * are in vbus_ports.c, vbus_relay.c and vbus_links.c (vbus_internal.h). */
#include "vbus/vbus_internal.h"
#include "common/fd_util.h"

#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/inotify.h>
#include <sys/stat.h>
#include <sys/timerfd.h>
#include <unistd.h>

void fap_vbus_options_init(fap_vbus_options *o)
{
    if (!o)
        return;
    memset(o, 0, sizeof *o);
    o->n_ports = 2;
}

static void bus_destroy(fap_vbus *b)
{
    lf_vbus_remove_links(b);
    for (unsigned i = 0; i < FAP_VBUS_MAX_PORTS; i++) {
        vbus_port *pt = &b->port[i];
        lf_pty_close(&pt->pty);
        free(pt->link);
        free(pt->outq);
    }
    free(b->dir);
    lf_wire_free(&b->wire);
    lf_capture_close(&b->cap);
    lf_close_fds((const int[]){b->evfd, b->tfd, b->infd}, 3);
    free(b->rbuf);
    pthread_cond_destroy(&b->cv);
    pthread_mutex_destroy(&b->mu);
    free(b);
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

    lf_wire_sink sink = lf_vbus_sink(b);
    int err = lf_wire_init(&b->wire, o->n_ports, o->baud, o->echo, o->seed, &sink);
    if (err)
        goto fail;
    err = lf_vbus_make_dir(b, o->link_dir);
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
            lf_vbus_port_watch(b, pt);
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
    err = -pthread_create(&b->thread, NULL, lf_vbus_relay_main, b);
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
    lf_vbus_live_add(b);
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
    lf_vbus_wake(b);
    lf_vbus_live_remove(b);
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

/* The control calls on one port: b locked when port is one of its ports
 * (1), else nothing locked (0: -EINVAL). */
static int lock_port(fap_vbus *b, unsigned port)
{
    if (!b || port >= b->n_ports)
        return 0;
    pthread_mutex_lock(&b->mu);
    return 1;
}

/* A wire model control on one port, under the lock. */
static int wire_control(fap_vbus *b, unsigned port, unsigned n,
                        void (*fn)(lf_wire *, unsigned, unsigned))
{
    if (!lock_port(b, port))
        return -EINVAL;
    fn(&b->wire, port, n);
    pthread_mutex_unlock(&b->mu);
    return 0;
}

int fap_vbus_drop_next(fap_vbus *b, unsigned port, unsigned n)
{
    return wire_control(b, port, n, lf_wire_drop_next);
}

int fap_vbus_corrupt_next(fap_vbus *b, unsigned port, unsigned n)
{
    return wire_control(b, port, n, lf_wire_corrupt_next);
}

int fap_vbus_silence(fap_vbus *b, unsigned port, unsigned ms)
{
    if (!lock_port(b, port))
        return -EINVAL;
    lf_ns now = lf_now_ns();
    lf_wire_silence(&b->wire, port, now + (lf_ns)ms * LF_NS_PER_MS);
    lf_capture_event(&b->cap, now, "silence", "port=%u ms=%u", port, ms);
    pthread_mutex_unlock(&b->mu);
    return 0;
}

int fap_vbus_disconnect(fap_vbus *b, unsigned port, unsigned ms)
{
    if (!lock_port(b, port))
        return -EINVAL;
    if (b->closing) {
        pthread_mutex_unlock(&b->mu);
        return -ESHUTDOWN;
    }
    b->port[port].disconnect_req = 1;
    b->port[port].disconnect_ms = ms;
    uint64_t gen = ++b->req_gen;
    lf_vbus_wake(b);
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
