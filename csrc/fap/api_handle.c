/* The handle API (fapx.h): queues and slave list shared with the engine
 * thread under one mutex, waits on a CLOCK_MONOTONIC condition variable,
 * an eventfd for wake-ups and a level-style eventfd for notification. */
#include "fap/fapx_internal.h"
#include "port/port_cancel.h"
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/timerfd.h>
#include <unistd.h>

void fapx_options_init(fapx_options *o)
{
    if (!o)
        return;
    memset(o, 0, sizeof *o);
    o->mode = FAPX_MASTER;
    fap_port_options_init(&o->port);
}

fap_port_options *fapx_options_port(fapx_options *o)
{
    return o ? &o->port : NULL;
}

void lf_fapx_fill_defaults(fapx_options *o)
{
    if (!o->idc_us)         o->idc_us = LF_FAP_DEFAULT_IDC / LF_NS_PER_US;
    if (!o->id_answer_us)   o->id_answer_us = LF_FAP_DEFAULT_ID_ANSWER / LF_NS_PER_US;
    if (!o->data_done_us)   o->data_done_us = LF_FAP_DEFAULT_DATA_DONE / LF_NS_PER_US;
    if (!o->send_budget_us) o->send_budget_us = LF_FAP_DEFAULT_BUDGET / LF_NS_PER_US;
    if (!o->reopen_us)      o->reopen_us = 200000u;
    if (!o->rx_depth)       o->rx_depth = FAPX_DEFAULT_RX_DEPTH;
    if (!o->tx_depth)       o->tx_depth = FAPX_DEFAULT_TX_DEPTH;
    if (!o->ev_depth)       o->ev_depth = FAPX_DEFAULT_EV_DEPTH;
}

void lf_fapx_wake(fapx *h)
{
    uint64_t one = 1;
    if (write(h->wake_fd, &one, sizeof one) < 0) { /* counter saturated: already awake */ }
}

int lf_fapx_stopping(fapx *h)
{
    pthread_mutex_lock(&h->lock);
    int stop = h->stop;
    pthread_mutex_unlock(&h->lock);
    return stop;
}

int lf_fapx_create(fapx **out, const char *path, const fapx_options *opts)
{
    if (!out || !path || !opts)
        return -EINVAL;
    fapx_options o = *opts;
    lf_fapx_fill_defaults(&o);
    if (o.rx_depth > 1u << 20 || o.tx_depth > 1u << 20 || o.ev_depth > 1u << 20)
        return -EINVAL;
    fapx *h = calloc(1, sizeof *h);
    if (!h)
        return -ENOMEM;
    h->o = o;
    h->mode = -1;
    h->wake_fd = h->notify_fd = h->timer_fd = h->epoll_fd = h->hold_epoll_fd = h->cancel_fd = -1;
    int err = -ENOMEM;
    if (lf_ring_init(&h->rx, o.rx_depth, sizeof(lf_fapx_item)) ||
        lf_ring_init(&h->tx, o.tx_depth, sizeof(lf_fapx_item)) ||
        lf_ring_init(&h->ev, o.ev_depth, sizeof(fapx_event)))
        goto fail;
    h->wake_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    h->notify_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    h->timer_fd = timerfd_create(CLOCK_MONOTONIC, TFD_CLOEXEC | TFD_NONBLOCK);
    h->epoll_fd = epoll_create1(EPOLL_CLOEXEC);
    h->hold_epoll_fd = epoll_create1(EPOLL_CLOEXEC);
    h->cancel_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (h->wake_fd < 0 || h->notify_fd < 0 || h->timer_fd < 0 || h->epoll_fd < 0 ||
        h->hold_epoll_fd < 0 || h->cancel_fd < 0) {
        err = -errno;
        goto fail;
    }
    /* Two sets for the handle's life: the engine waits in epoll_fd (wake,
     * timer, port) and, while a frame's bytes are held back, in
     * hold_epoll_fd (wake, timer): no epoll_ctl per frame. */
    for (int i = 0; i < 2; i++) {
        int ep = i ? h->hold_epoll_fd : h->epoll_fd;
        struct epoll_event ee = { .events = EPOLLIN, .data.u32 = LF_FAPX_TAG_WAKE };
        if (epoll_ctl(ep, EPOLL_CTL_ADD, h->wake_fd, &ee) < 0) {
            err = -errno;
            goto fail;
        }
        ee.data.u32 = LF_FAPX_TAG_TIMER;
        if (epoll_ctl(ep, EPOLL_CTL_ADD, h->timer_fd, &ee) < 0) {
            err = -errno;
            goto fail;
        }
    }
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&h->cond, &ca);
    pthread_condattr_destroy(&ca);
    pthread_mutex_init(&h->lock, NULL);
    lf_trace_init(&h->trace);
    if (o.trace)   /* before the engine starts: it sees the first frame */
        lf_trace_set(&h->trace, o.trace, o.trace_ctx);
    /* a stop's grace period over, cancel_fd ends the write in progress; during
     * the open the caller's cancel (o.cancel_fd) is the one watched: the
     * port reads *(&port_cancel) at each wait, so switching the int after
     * the open hands the port to the engine's own fd (no thread but this
     * one uses the port before the engine thread starts) */
    h->port_cancel = o.cancel_fd > 0 ? o.cancel_fd : h->cancel_fd;
    err = lf_port_open_cancellable(&h->port, path, &o.port, &h->port_cancel);
    h->port_cancel = h->cancel_fd;
    if (err < 0) {
        pthread_cond_destroy(&h->cond);
        pthread_mutex_destroy(&h->lock);
        lf_trace_destroy(&h->trace);
        goto fail;
    }
    *out = h;
    return 0;
fail:
    if (h->wake_fd >= 0) close(h->wake_fd);
    if (h->notify_fd >= 0) close(h->notify_fd);
    if (h->timer_fd >= 0) close(h->timer_fd);
    if (h->epoll_fd >= 0) close(h->epoll_fd);
    if (h->hold_epoll_fd >= 0) close(h->hold_epoll_fd);
    if (h->cancel_fd >= 0) close(h->cancel_fd);
    lf_ring_free(&h->rx);
    lf_ring_free(&h->tx);
    lf_ring_free(&h->ev);
    free(h);
    return err;
}

/* A master is node 0, a slave 1..31. */
static int mode_id_ok(unsigned mode, unsigned id)
{
    return mode == FAPX_MASTER ? id == 0 : mode == FAPX_SLAVE && id != 0 && id <= FAPX_MAX_ID;
}

int lf_fapx_start(fapx *h, unsigned mode, unsigned id)
{
    if (!mode_id_ok(mode, id))
        return -EINVAL;
    lf_fapx_stop(h);
    pthread_mutex_lock(&h->lock);
    h->mode = (int)mode;
    h->id = id;
    h->o.mode = mode;
    h->o.id = id;
    h->stop = 0;
    h->exited = 0;
    h->tx_abandoned_now = 0;
    h->tx_kick = 1;
    h->active_pub = 0;
    if (mode == FAPX_SLAVE)
        h->want_listed = 0;           /* a slave keeps no list */
    pthread_mutex_unlock(&h->lock);
    uint64_t v;
    if (read(h->cancel_fd, &v, sizeof v) < 0) { /* not set: nothing to clear */ }
    /* Bytes that piled up since fapInit (or the last fapConfig) are stale
     * frames nobody was listening for: drop them. */
    fap_port_flush(h->port);
    int rc = pthread_create(&h->thread, NULL, lf_fapx_engine_main, h);
    if (rc != 0)
        return -rc;
    pthread_mutex_lock(&h->lock);
    h->started = 1;
    pthread_mutex_unlock(&h->lock);
    return 0;
}

void lf_fapx_stop(fapx *h)
{
    pthread_mutex_lock(&h->lock);
    int started = h->started;
    h->stop = 1;
    h->started = 0;
    pthread_mutex_unlock(&h->lock);
    if (!started)
        return;
    lf_fapx_wake(h);
    /* The engine leaves between two frames; a write the line does not
     * take within the grace period is abandoned (cancel_fd, port_cancel.h). */
    struct timespec ts = lf_ns_to_timespec(lf_now_ns() + FAPX_STOP_GRACE_MS * LF_NS_PER_MS);
    pthread_mutex_lock(&h->lock);
    while (!h->exited && pthread_cond_timedwait(&h->cond, &h->lock, &ts) != ETIMEDOUT)
        ;
    int exited = h->exited;
    pthread_mutex_unlock(&h->lock);
    if (!exited) {
        uint64_t one = 1;
        if (write(h->cancel_fd, &one, sizeof one) < 0) { /* already set */ }
    }
    pthread_join(h->thread, NULL);
    pthread_mutex_lock(&h->lock);
    h->tx_inflight = 0;
    h->active_pub = 0;
    pthread_cond_broadcast(&h->cond);
    pthread_mutex_unlock(&h->lock);
}

void lf_fapx_destroy(fapx *h)
{
    lf_fapx_destroy_stats(h, NULL);
}

void lf_fapx_destroy_stats(fapx *h, fapx_stats *final)
{
    if (!h)
        return;
    lf_fapx_stop(h);
    pthread_mutex_lock(&h->lock);
    h->stats.tx_abandoned += h->tx.count;   /* queued DATA nobody will send */
    if (final)
        *final = h->stats;
    h->closing = 1;
    pthread_cond_broadcast(&h->cond);
    while (h->waiters)                 /* let blocked readers leave first */
        pthread_cond_wait(&h->cond, &h->lock);
    pthread_mutex_unlock(&h->lock);
    fap_port_close(h->port);
    close(h->wake_fd);
    close(h->notify_fd);
    close(h->timer_fd);
    close(h->epoll_fd);
    close(h->hold_epoll_fd);
    close(h->cancel_fd);
    lf_ring_free(&h->rx);
    lf_ring_free(&h->tx);
    lf_ring_free(&h->ev);
    pthread_cond_destroy(&h->cond);
    pthread_mutex_destroy(&h->lock);
    lf_trace_destroy(&h->trace);
    free(h);
}

int fapx_open(fapx **out, const char *path, const fapx_options *o)
{
    if (!out || !path || !o)
        return -EINVAL;
    if (!mode_id_ok(o->mode, o->id))   /* before the port is opened */
        return -EINVAL;
    fapx *h;
    int rc = lf_fapx_create(&h, path, o);
    if (rc < 0)
        return rc;
    rc = lf_fapx_start(h, o->mode, o->id);
    if (rc < 0) {
        lf_fapx_destroy(h);
        return rc;
    }
    *out = h;
    return 0;
}

void fapx_close(fapx *h)
{
    lf_fapx_destroy(h);
}

void fapx_close_stats(fapx *h, fapx_stats *out)
{
    lf_fapx_destroy_stats(h, out);
}

/* ---- slave list ---- */

static int list_check_locked(fapx *h, unsigned id)
{
    if (h->closing)
        return -ESHUTDOWN;
    if (h->mode == FAPX_SLAVE)
        return -EPERM;
    if (id == 0 || id > FAPX_MAX_ID)
        return -EINVAL;
    return 0;
}

int fapx_add_slave(fapx *h, unsigned id)
{
    if (!h)
        return -EINVAL;
    pthread_mutex_lock(&h->lock);
    int rc = list_check_locked(h, id);
    if (rc == 0 && (h->want_listed >> id & 1u))
        rc = -EEXIST;
    if (rc == 0) {
        h->want_listed |= 1u << id;
        h->add_epoch[id]++;
        h->active_pub &= ~(1u << id);
    }
    pthread_mutex_unlock(&h->lock);
    if (rc == 0)
        lf_fapx_wake(h);
    return rc;
}

int fapx_remove_slave(fapx *h, unsigned id)
{
    if (!h)
        return -EINVAL;
    pthread_mutex_lock(&h->lock);
    int rc = list_check_locked(h, id);
    if (rc == 0 && !(h->want_listed >> id & 1u))
        rc = -ENOENT;
    if (rc == 0) {
        h->want_listed &= ~(1u << id);
        h->active_pub &= ~(1u << id);
    }
    pthread_mutex_unlock(&h->lock);
    if (rc == 0)
        lf_fapx_wake(h);
    return rc;
}

int fapx_slave_active(fapx *h, unsigned id)
{
    if (!h)
        return -EINVAL;
    pthread_mutex_lock(&h->lock);
    int rc = list_check_locked(h, id);
    if (rc == 0)
        rc = !(h->want_listed >> id & 1u) ? -ENOENT : (int)(h->active_pub >> id & 1u);
    pthread_mutex_unlock(&h->lock);
    return rc;
}

uint32_t fapx_listed_mask(fapx *h)
{
    if (!h)
        return 0;
    pthread_mutex_lock(&h->lock);
    uint32_t v = h->want_listed;
    pthread_mutex_unlock(&h->lock);
    return v;
}

uint32_t fapx_active_mask(fapx *h)
{
    if (!h)
        return 0;
    pthread_mutex_lock(&h->lock);
    uint32_t v = h->active_pub & h->want_listed;
    pthread_mutex_unlock(&h->lock);
    return v;
}

/* ---- data ---- */

/* Absolute CLOCK_MONOTONIC deadline for a timeout in ms (< 0 = never). */
static struct timespec deadline_ts(int timeout_ms, int *forever)
{
    *forever = timeout_ms < 0;
    return lf_ns_to_timespec(lf_now_ns() + (lf_ns)(timeout_ms < 0 ? 0 : timeout_ms) * LF_NS_PER_MS);
}

/* Wait on the condition until `ready` or the deadline (lock held). */
#define WAIT_UNTIL(h, ready, timeout_ms, rc) do { \
    int forever_; struct timespec ts_ = deadline_ts((timeout_ms), &forever_); \
    (h)->waiters++; \
    while (!(ready) && !(h)->closing) { \
        int e_ = forever_ ? pthread_cond_wait(&(h)->cond, &(h)->lock) \
                          : pthread_cond_timedwait(&(h)->cond, &(h)->lock, &ts_); \
        if (e_ == ETIMEDOUT && !(ready)) { (rc) = -ETIMEDOUT; break; } \
    } \
    if (!(ready) && (h)->closing) (rc) = -ESHUTDOWN; \
    (h)->waiters--; \
    if ((h)->closing) pthread_cond_broadcast(&(h)->cond); \
} while (0)

static int tx_common(fapx *h, unsigned dst, const void *data, size_t len, int wait, int timeout_ms)
{
    if (!h || !data)
        return -EINVAL;
    if (len == 0 || len > FAPX_MAX_DATA || dst > FAPX_MAX_ID)
        return -EINVAL;
    pthread_mutex_lock(&h->lock);
    int rc = 0;
    if (wait && !(h->mode >= 0 && dst == h->id))
        WAIT_UNTIL(h, h->tx.count < h->tx.cap, timeout_ms, rc);
    if (rc != 0)
        ;
    else if (h->closing)
        rc = -ESHUTDOWN;
    else if (h->mode >= 0 && dst == h->id)
        rc = -EINVAL;                 /* the master is 0: it cannot send to 0 either */
    else {
        lf_fapx_item *it = lf_ring_tail(&h->tx);
        if (!it) {
            rc = -EAGAIN;
        } else {
            it->peer = (uint8_t)dst;
            it->len = (uint16_t)len;
            memcpy(it->data, data, len);
            lf_ring_commit(&h->tx);
            h->tx_kick = 1;
        }
    }
    pthread_mutex_unlock(&h->lock);
    if (rc == 0)
        lf_fapx_wake(h);
    return rc;
}

int fapx_tx(fapx *h, unsigned dst, const void *data, size_t len)
{
    return tx_common(h, dst, data, len, 0, 0);
}

int fapx_tx_wait(fapx *h, unsigned dst, const void *data, size_t len, int timeout_ms)
{
    return tx_common(h, dst, data, len, 1, timeout_ms);
}


int fapx_flush(fapx *h, int timeout_ms)
{
    if (!h)
        return -EINVAL;
    pthread_mutex_lock(&h->lock);
    int rc = 0;
    WAIT_UNTIL(h, (h->tx.count == 0 && !h->tx_inflight) || !h->started, timeout_ms, rc);
    if (rc == 0 && (h->tx.count || h->tx_abandoned_now))
        rc = -ESHUTDOWN;               /* no engine running to send it, or a stop dropped it */
    pthread_mutex_unlock(&h->lock);
    return rc;
}

static void clear_notify_locked(fapx *h)
{
    if (h->notify_set && h->rx.count == 0 && h->ev.count == 0) {
        uint64_t v;
        if (read(h->notify_fd, &v, sizeof v) == sizeof v || errno == EAGAIN)
            h->notify_set = 0;
    }
}

static int rx_take_locked(fapx *h, void *buf, size_t cap, unsigned *src)
{
    lf_fapx_item *it = lf_ring_head(&h->rx);
    if (!it)
        return -EAGAIN;
    if (cap < it->len)
        return -EMSGSIZE;
    memcpy(buf, it->data, it->len);
    if (src)
        *src = it->peer;
    int n = it->len;
    lf_ring_pop(&h->rx);
    clear_notify_locked(h);
    return n;
}

int fapx_rx(fapx *h, void *buf, size_t cap, unsigned *src)
{
    if (!h || !buf)
        return -EINVAL;
    pthread_mutex_lock(&h->lock);
    int rc = rx_take_locked(h, buf, cap, src);
    pthread_mutex_unlock(&h->lock);
    return rc;
}

int fapx_rx_wait(fapx *h, void *buf, size_t cap, unsigned *src, int timeout_ms)
{
    if (!h || !buf)
        return -EINVAL;
    pthread_mutex_lock(&h->lock);
    int rc = 0;
    WAIT_UNTIL(h, h->rx.count > 0, timeout_ms, rc);
    if (rc == 0)
        rc = rx_take_locked(h, buf, cap, src);
    pthread_mutex_unlock(&h->lock);
    return rc;
}

static int ev_take_locked(fapx *h, fapx_event *ev)
{
    fapx_event *e = lf_ring_head(&h->ev);
    if (!e)
        return -EAGAIN;
    *ev = *e;
    lf_ring_pop(&h->ev);
    clear_notify_locked(h);
    return 0;
}

int fapx_event_get(fapx *h, fapx_event *ev)
{
    if (!h || !ev)
        return -EINVAL;
    pthread_mutex_lock(&h->lock);
    int rc = ev_take_locked(h, ev);
    pthread_mutex_unlock(&h->lock);
    return rc;
}

int fapx_event_wait(fapx *h, fapx_event *ev, int timeout_ms)
{
    if (!h || !ev)
        return -EINVAL;
    pthread_mutex_lock(&h->lock);
    int rc = 0;
    WAIT_UNTIL(h, h->ev.count > 0, timeout_ms, rc);
    if (rc == 0)
        rc = ev_take_locked(h, ev);
    pthread_mutex_unlock(&h->lock);
    return rc;
}

int fapx_notify_fd(fapx *h)
{
    return h ? h->notify_fd : -EINVAL;
}

void fapx_set_trace(fapx *h, fap_trace_fn fn, void *ctx)
{
    if (h)
        lf_trace_set(&h->trace, fn, ctx);
}

void fapx_set_callback(fapx *h, fapx_callback cb, void *ctx)
{
    if (!h)
        return;
    pthread_mutex_lock(&h->lock);
    h->cb = cb;
    h->cb_ctx = ctx;
    pthread_mutex_unlock(&h->lock);
}

void fapx_get_stats(fapx *h, fapx_stats *out)
{
    if (!h || !out)
        return;
    pthread_mutex_lock(&h->lock);
    *out = h->stats;
    pthread_mutex_unlock(&h->lock);
}

unsigned fapx_rx_pending(fapx *h)
{
    if (!h)
        return 0;
    pthread_mutex_lock(&h->lock);
    unsigned n = h->rx.count;
    pthread_mutex_unlock(&h->lock);
    return n;
}

unsigned fapx_tx_pending(fapx *h)
{
    if (!h)
        return 0;
    pthread_mutex_lock(&h->lock);
    unsigned n = h->tx.count + (unsigned)h->tx_inflight;
    pthread_mutex_unlock(&h->lock);
    return n;
}

fap_port *fapx_port(fapx *h)
{
    return h ? h->port : NULL;
}

const char *fapx_strerror(int err)
{
    switch (err) {
    case 0:           return "success";
    case -EINVAL:     return "invalid argument (ID, size or option out of range)";
    case -EEXIST:     return "slave already listed";
    case -ENOENT:     return "slave not listed";
    case -EPERM:      return "slave-list call on a slave node";
    case -EAGAIN:     return "queue full or empty";
    case -ETIMEDOUT:  return "timed out";
    case -EMSGSIZE:   return "buffer smaller than the frame";
    case -ESHUTDOWN:  return "handle closing or engine stopped";
    default:          return fap_port_strerror(err);
    }
}

const char *fapx_event_name(int type)
{
    switch (type) {
    case FAPX_EV_SLAVE_ACTIVE:   return "slave-active";
    case FAPX_EV_SLAVE_INACTIVE: return "slave-inactive";
    case FAPX_EV_ID_TIMEOUT:     return "id-timeout";
    case FAPX_EV_QUERIED:        return "queried";
    case FAPX_EV_RX:             return "rx";
    case FAPX_EV_PORT_LOST:      return "port-lost";
    case FAPX_EV_PORT_REOPENED:  return "port-reopened";
    case FAPX_EV_RX_OVERFLOW:    return "rx-overflow";
    default:                     return "?";
    }
}
