/* vbus_relay.c - the virtual bus's relay thread.
 *
 * One relay thread polls every pty master, an inotify fd (nodes opening
 * and closing the ports), an eventfd (wake-ups from the control calls and
 * close) and a timerfd (absolute CLOCK_MONOTONIC: paced deliveries,
 * reconnects, capture lines). It never busy-loops. What each port
 * receives is decided by the sans-I/O wire model (vbus_wire.c); this file
 * only moves bytes between fds and that model. */
#include "vbus/vbus_internal.h"

#include <errno.h>
#include <poll.h>
#include <unistd.h>

#include "common/mono_timerfd.h"

/* ---- wire model sink (called with the mutex held) --------------------- */

static void sink_deliver(void *ctx, unsigned sender, uint64_t to, const uint8_t *data,
                         size_t n, lf_ns t)
{
    fap_vbus *b = ctx;
    lf_capture_data(&b->cap, t, sender, data, n);
    for (unsigned q = 0; q < b->n_ports; q++)
        if (to & (1ull << q))
            lf_vbus_port_write(b, &b->port[q], data, n);
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

lf_wire_sink lf_vbus_sink(fap_vbus *b)
{
    return (lf_wire_sink){ .ctx = b, .deliver = sink_deliver, .collision = sink_collision,
                           .fault = sink_fault };
}

void lf_vbus_wake(fap_vbus *b)
{
    uint64_t one = 1;
    ssize_t w = write(b->evfd, &one, sizeof one);
    (void)w;   /* EAGAIN only when the counter is already huge: still awake */
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
                lf_vbus_port_disconnect(b, i, b->port[i].disconnect_ms, now);
            }
        }
        b->done_gen = b->req_gen;
        pthread_cond_broadcast(&b->cv);
    }
    lf_ns next = LF_NEVER;
    for (unsigned i = 0; i < b->n_ports; i++) {
        if (b->port[i].reconnect_at <= now)
            lf_vbus_port_reconnect(b, i, now);
        if (b->port[i].reconnect_at < next)
            next = b->port[i].reconnect_at;
    }
    lf_vbus_attach_events(b);
    lf_wire_advance(&b->wire, now);
    lf_ns due = lf_wire_next_due(&b->wire);
    if (due < next)
        next = due;
    lf_capture_tick(&b->cap, now);
    due = lf_capture_due(&b->cap);
    return due < next ? due : next;
}

void *lf_vbus_relay_main(void *arg)
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
                    lf_vbus_attach_events(b);   /* opens that came before these bytes */
                    lf_wire_send(&b->wire, (unsigned)who[k], b->rbuf, (size_t)got, now);
                } else if (want && (pfd[k].revents & (POLLHUP | POLLERR)) &&
                           (got == 0 || (errno != EAGAIN && errno != EINTR))) {
                    /* a broken pty would wake us forever: replace it, as a
                     * disconnect of 0 ms (never seen with our slave fd open) */
                    lf_vbus_port_disconnect(b, (unsigned)who[k], 0, now);
                    continue;
                }
            }
            if (pfd[k].revents & POLLOUT)
                lf_vbus_outq_flush(b, pt);
        }
    }
    pthread_mutex_unlock(&b->mu);
    return NULL;
}

