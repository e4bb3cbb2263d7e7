/* port.c - fap_port lifecycle: options, open/close/reopen, accessors,
 * stats, and the fd borrowing that makes a vanished device safe to close
 * while other threads are inside read/write. */
#include "port/port_internal.h"

#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "common/fd_util.h"
#include "common/mono_clock.h"
#include "port/port_link.h"

void fap_port_options_init(fap_port_options *o)
{
    if (!o)
        return;
    memset(o, 0, sizeof *o);
    o->baud = 115200;
    o->rs485_mode = FAP_RS485_AUTO;
    o->rts_active_high = FAP_PORT_KEEP;
    o->rx_during_tx = FAP_PORT_KEEP;
    o->delay_before_send_us = FAP_PORT_KEEP_DELAY;
    o->delay_after_send_us = FAP_PORT_KEEP_DELAY;
    o->exclusive = 1;
    o->low_latency = FAP_PORT_KEEP;
}

static int validate_options(const fap_port_options *in, fap_port_options *out)
{
    if (in)
        *out = *in;
    else
        fap_port_options_init(out);
    if (!lf_port_baud_ok(out->baud))
        return -EINVAL;
    switch (out->rs485_mode) {
    case FAP_RS485_AUTO:
    case FAP_RS485_KERNEL:
    case FAP_RS485_SOFT_RTS:
    case FAP_RS485_NONE:
        break;
    case FAP_RS485_GPIO:
        if (!out->gpio_chip || !out->gpio_chip[0])
            return -EINVAL;
        break;
    default:
        return -EINVAL;
    }
    if (out->rts_active_high != FAP_PORT_KEEP)
        out->rts_active_high = out->rts_active_high != 0;
    if (out->rx_during_tx != FAP_PORT_KEEP)
        out->rx_during_tx = out->rx_during_tx != 0;
    out->echo_suppression = out->echo_suppression != 0;
    out->exclusive = out->exclusive != 0;
    if (out->low_latency != FAP_PORT_KEEP)
        out->low_latency = out->low_latency != 0;
    return 0;
}

void lf_port_watch(fap_port *p, int fd)
{
    struct epoll_event ev = {.events = EPOLLIN, .data.fd = fd};
    (void)epoll_ctl(p->poll_fd, EPOLL_CTL_ADD, fd, &ev);
}

void lf_port_unwatch(fap_port *p, int fd)
{
    if (fd >= 0)
        (void)epoll_ctl(p->poll_fd, EPOLL_CTL_DEL, fd, NULL);
}

void lf_port_pend_signal(fap_port *p, int nonempty)
{
    uint64_t v = 1;
    if (nonempty) {
        if (write(p->pend_efd, &v, sizeof v) < 0) { /* counter full: still readable */ }
    } else {
        if (read(p->pend_efd, &v, sizeof v) < 0) { /* already clear */ }
    }
}

/* Unwatch and close a connection. */
static void conn_drop(fap_port *p, lf_port_conn *c)
{
    lf_port_unwatch(p, c->fd);
    lf_port_conn_close(p, c);
}

static void port_free(fap_port *p)
{
    lf_close_fds((const int[]){p->poll_fd, p->pend_efd, p->intr_fd}, 3);
    free(p->pend);
    pthread_cond_destroy(&p->idle_cv);
    pthread_mutex_destroy(&p->st_mu);
    pthread_mutex_destroy(&p->rx_mu);
    pthread_mutex_destroy(&p->tx_mu);
    free(p->path);
    free(p->gpio_chip);
    if (p->be->destroy)
        p->be->destroy(p->ctx);
    free(p);
}

int lf_port_open_transport(fap_port **out, const char *path, const fap_port_options *o,
                           const lf_port_transport *be, void *ctx, const int *cancel_fd)
{
    if (!out || !path || !be) {
        if (be && be->destroy)
            be->destroy(ctx);   /* the port would have owned it */
        return -EINVAL;
    }
    fap_port *p = calloc(1, sizeof *p);
    if (!p) {
        if (be->destroy)
            be->destroy(ctx);
        return -ENOMEM;
    }
    p->be = be;
    p->ctx = ctx;
    /* set before the connect: a network open's waits (name lookup, connect,
     * RFC 2217 negotiation) end when it turns readable, like every later one */
    p->cancel_fd = cancel_fd;
    if (be->attach)
        be->attach(ctx, &p->cancel_fd);
    p->conn.fd = p->conn.gpio_fd = p->conn.latency_saved = -1;
    p->poll_fd = p->pend_efd = p->intr_fd = -1;
    pthread_mutex_init(&p->tx_mu, NULL);
    pthread_mutex_init(&p->rx_mu, NULL);
    pthread_mutex_init(&p->st_mu, NULL);
    pthread_cond_init(&p->idle_cv, NULL);
    int err = validate_options(o, &p->opt);
    if (!err)
        err = lf_port_rt_open(p);   /* real-time option refused: the open fails */
    if (err) {
        port_free(p);
        return err;
    }
    p->path = strdup(path);
    int nomem = !p->path;
    if (p->opt.gpio_chip) {   /* ours: reopen uses it after the caller's is gone */
        p->gpio_chip = strdup(p->opt.gpio_chip);
        nomem |= !p->gpio_chip;
        p->opt.gpio_chip = p->gpio_chip;
    }
    p->poll_fd = epoll_create1(EPOLL_CLOEXEC);
    p->pend_efd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (nomem || p->poll_fd < 0 || p->pend_efd < 0) {
        err = nomem ? -ENOMEM : -errno;
        port_free(p);
        return err;
    }
    lf_port_watch(p, p->pend_efd);
    err = lf_port_conn_open(p, &p->conn);
    if (err) {
        port_free(p);
        return err;
    }
    lf_port_watch(p, p->conn.fd);
    *out = p;
    return 0;
}

/* (fap_port_open and the choice of a transport: port_transport.c) */

unsigned fap_port_caps(const fap_port *p)
{
    return p ? p->be->caps : 0;
}

lf_ns lf_port_link_slack_ns(const fap_port *p)
{
    return p && p->be->slack_ns ? (lf_ns)p->be->slack_ns(p->ctx) : 0;
}

size_t fap_port_warning(const fap_port *p, char *buf, size_t n)
{
    if (buf && n)
        buf[0] = '\0';
    if (!p || !p->be->warning)
        return 0;
    return p->be->warning(p->ctx, buf, n);
}

void fap_port_close(fap_port *p)
{
    if (!p)
        return;
    pthread_mutex_lock(&p->st_mu);
    while (p->busy > 0)
        pthread_cond_wait(&p->idle_cv, &p->st_mu);
    pthread_mutex_unlock(&p->st_mu);
    conn_drop(p, &p->conn);
    port_free(p);
}

int fap_port_reopen(fap_port *p)
{
    if (!p)
        return -EINVAL;
    pthread_mutex_lock(&p->tx_mu);
    pthread_mutex_lock(&p->rx_mu);
    pthread_mutex_lock(&p->st_mu);
    while (p->busy > 0)
        pthread_cond_wait(&p->idle_cv, &p->st_mu);
    lf_port_conn old = p->conn;
    p->conn.fd = p->conn.gpio_fd = p->conn.latency_saved = -1;   /* old owns them now */
    if (!p->gone_err)
        p->gone_err = -ENODEV;   /* between close and open: no device */
    pthread_mutex_unlock(&p->st_mu);

    conn_drop(p, &old);
    /* Input parked from the old device belongs to a dead stream. */
    p->pend_off = p->pend_len = 0;
    lf_port_pend_signal(p, 0);
    lf_port_conn fresh;
    int err = lf_port_conn_open(p, &fresh);
    if (err == 0)
        lf_port_watch(p, fresh.fd);

    pthread_mutex_lock(&p->st_mu);
    if (err == 0) {
        p->conn = fresh;
        p->gone_err = 0;
        p->last_rx_ns = 0;
        p->stats.reopens++;
    } else {
        p->gone_err = err;
    }
    pthread_mutex_unlock(&p->st_mu);
    pthread_mutex_unlock(&p->rx_mu);
    pthread_mutex_unlock(&p->tx_mu);
    return err;
}

int lf_port_acquire(fap_port *p, int *fd, fap_rs485_mode *mode)
{
    pthread_mutex_lock(&p->st_mu);
    if (p->gone_err || p->conn.fd < 0) {
        int err = p->gone_err ? p->gone_err : -EIO;
        pthread_mutex_unlock(&p->st_mu);
        return err;
    }
    p->busy++;
    *fd = p->conn.fd;
    if (mode)
        *mode = p->conn.mode;
    pthread_mutex_unlock(&p->st_mu);
    return 0;
}

void lf_port_release(fap_port *p)
{
    lf_port_conn dead = {.fd = -1};
    pthread_mutex_lock(&p->st_mu);
    if (p->busy == 1 && p->gone_err && p->conn.fd >= 0) {
        /* Last user of a vanished device: close it now, so a USB adapter's
         * node is free for the replug. Stay busy until it is closed, so a
         * reopen cannot race with this close (its flock would see ours). */
        dead = p->conn;
        dead.tio_restore = 0;   /* gone: no pin or line settings to put back */
        p->conn.fd = p->conn.gpio_fd = p->conn.latency_saved = -1;
    } else {
        p->busy--;
        if (p->busy == 0)
            pthread_cond_broadcast(&p->idle_cv);
    }
    pthread_mutex_unlock(&p->st_mu);
    if (dead.fd < 0)
        return;
    conn_drop(p, &dead);
    pthread_mutex_lock(&p->st_mu);
    if (--p->busy == 0)
        pthread_cond_broadcast(&p->idle_cv);
    pthread_mutex_unlock(&p->st_mu);
}

void lf_port_note_error(fap_port *p, int err)
{
    if (!fap_port_error_is_gone(err))
        return;
    pthread_mutex_lock(&p->st_mu);
    if (!p->gone_err)
        p->gone_err = err;
    pthread_mutex_unlock(&p->st_mu);
}

fap_rs485_mode fap_port_mode(const fap_port *p)
{
    if (!p)
        return FAP_RS485_NONE;
    fap_port *mp = (fap_port *)p;   /* the lock is not part of the value */
    pthread_mutex_lock(&mp->st_mu);
    fap_rs485_mode m = p->conn.mode;
    pthread_mutex_unlock(&mp->st_mu);
    return m;
}

int fap_port_fd(const fap_port *p)
{
    if (!p)
        return -1;
    fap_port *mp = (fap_port *)p;
    pthread_mutex_lock(&mp->st_mu);
    int fd = p->gone_err || p->conn.fd < 0 ? -1 : p->poll_fd;
    pthread_mutex_unlock(&mp->st_mu);
    return fd;
}

const char *fap_port_path(const fap_port *p)
{
    return p ? p->path : NULL;
}

unsigned fap_port_baud(const fap_port *p)
{
    return p ? p->opt.baud : 0;
}

int64_t fap_port_now_ns(void)
{
    return lf_now_ns();
}

void fap_port_get_stats(const fap_port *p, fap_port_stats *out)
{
    if (!out)
        return;
    if (!p) {
        memset(out, 0, sizeof *out);
        return;
    }
    fap_port *mp = (fap_port *)p;
    pthread_mutex_lock(&mp->st_mu);
    *out = p->stats;
    pthread_mutex_unlock(&mp->st_mu);
}

/* A copy of the connection's settings, taken under the lock. */
static lf_port_conn conn_snapshot(const fap_port *p)
{
    fap_port *mp = (fap_port *)p;   /* the lock is not part of the value */
    pthread_mutex_lock(&mp->st_mu);
    lf_port_conn c = p->conn;
    pthread_mutex_unlock(&mp->st_mu);
    return c;
}

int fap_port_auto_errno(const fap_port *p)
{
    return p ? conn_snapshot(p).auto_errno : 0;
}

int fap_port_kernel_rs485(const fap_port *p, uint32_t *flags,
                          uint32_t *delay_before_ms, uint32_t *delay_after_ms)
{
    if (!p)
        return -EINVAL;
    lf_port_conn c = conn_snapshot(p);
    if (c.mode != FAP_RS485_KERNEL || !c.rs485_restore)
        return -ENOTTY;
    if (flags)
        *flags = c.rs485_active.flags;
    if (delay_before_ms)
        *delay_before_ms = c.rs485_active.delay_rts_before_send;
    if (delay_after_ms)
        *delay_after_ms = c.rs485_active.delay_rts_after_send;
    return 0;
}

int fap_port_rts_settings(const fap_port *p, int *active_high,
                          unsigned *delay_before_us, unsigned *delay_after_us)
{
    if (!p)
        return -EINVAL;
    lf_port_conn c = conn_snapshot(p);
    if (active_high)
        *active_high = c.rts_active_high;
    if (delay_before_us)
        *delay_before_us = c.delay_before_us;
    if (delay_after_us)
        *delay_after_us = c.delay_after_us;
    return 0;
}
