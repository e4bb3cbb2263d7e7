/* The engine thread of one FAP handle: epoll on the port fd, an eventfd
 * (wake-ups from fapx_tx, slave-list changes, close) and a timerfd armed at
 * the nearest CLOCK_MONOTONIC deadline (state machine timer, decoder
 * inter-byte gap, port reopen). It feeds received bytes to the decoder and
 * frames to the state machine, and transmits the state machine's outbox
 * through the port layer. While a frame is arriving it sleeps on the timer
 * for the frame's wire time instead of waking per byte; a master that
 * polled a slave sleeps until the DATA_DONE can be complete (the time
 * reply_predict.h learns) and reads it in one wake-up. When to read is the
 * read planner's (port/rx_plan.h): this loop is its event-driven driver.
 * No signals: nothing the host application sees. */
#include "fap/fapx_internal.h"
#include "fap/reply_predict.h"
#include "common/mono_timerfd.h"
#include "port/port_link.h"   /* the link's slack; fap_port_caps says what it is */
#include "port/rx_pacing.h"   /* the read planner (rx_plan.h) */
#include <errno.h>
#include <linux/time_types.h>   /* struct __kernel_timespec */
#include <sys/epoll.h>
#include <sys/prctl.h>
#include <sys/syscall.h>
#include <string.h>
#include <unistd.h>

/* ---- state machine callbacks (engine thread) ---- */

static void set_notify_locked(fapx *h)
{
    if (!h->notify_set) {
        uint64_t one = 1;
        if (write(h->notify_fd, &one, sizeof one) == sizeof one)
            h->notify_set = 1;
    }
}

static uint32_t consistent_ids_locked(const fapx *h)
{
    uint32_t ok = 0;
    for (unsigned id = 1; id <= LF_FAP_MAX_ID; id++)
        if (h->applied_epoch[id] == h->add_epoch[id])
            ok |= 1u << id;
    return ok & h->want_listed & h->applied_listed;
}

/* Copy the engine's counters into the shared snapshot (lock held). */
static void publish_locked(fapx *h)
{
    const lf_fap_sm_counts *c = h->mode == FAPX_MASTER ? &h->m.c : &h->s.c;
    const lf_fap_rx_counts *d = &h->dec.c;
    fapx_stats *st = &h->stats;
    st->frames_tx = h->ec.frames_tx;
    st->bytes_tx = h->ec.bytes_tx;
    st->frames_rx = d->frames;
    st->bytes_rx = d->bytes;
    st->data_tx = c->data_tx;
    st->data_rx = c->data_rx;
    st->crc_errors = d->crc_errors;
    st->framing_errors = d->framing_errors;
    st->gap_timeouts = d->gap_timeouts;
    st->garbage_bytes = d->garbage_bytes;
    st->id_timeouts = c->id_timeouts;
    st->data_done_timeouts = c->data_done_timeouts;
    st->collisions = h->ec.collisions;
    st->cycles = c->cycles;
    st->id_cycles = c->id_cycles;
    st->polls = c->polls;
    st->rx_dropped = h->ec.rx_dropped;
    st->tx_dropped = c->tx_dropped;
    st->write_errors = h->ec.write_errors;
    st->port_lost = h->ec.port_lost;
    st->port_reopened = h->ec.port_reopened;
    st->unexpected = c->unexpected;
    st->ev_dropped = h->ec.ev_dropped;
    st->tx_to_inactive = c->tx_to_inactive;
    st->tx_unconfirmed = c->tx_unconfirmed;
    st->tx_abandoned = h->ec.tx_abandoned;
    if (h->mode == FAPX_MASTER)
        h->active_pub = h->m.active & consistent_ids_locked(h);
}

static void call_back(fapx *h, int type, unsigned id, lf_ns now)
{
    fapx_callback cb;
    void *ctx;
    pthread_mutex_lock(&h->lock);
    cb = h->cb;
    ctx = h->cb_ctx;
    pthread_mutex_unlock(&h->lock);
    if (cb) {
        fapx_event ev = { .type = type, .id = id, .time_ns = now };
        cb(ctx, &ev);
    }
}

static void push_event(fapx *h, int type, unsigned id, lf_ns now)
{
    pthread_mutex_lock(&h->lock);
    fapx_event *ev = lf_ring_tail(&h->ev);
    if (!ev)
        h->ec.ev_dropped++;
    publish_locked(h);
    if (ev) {                       /* a full event queue keeps the oldest events */
        ev->type = type;
        ev->id = id;
        ev->time_ns = now;
        lf_ring_commit(&h->ev);
        set_notify_locked(h);
        if (h->waiters)
            pthread_cond_broadcast(&h->cond);
    }
    pthread_mutex_unlock(&h->lock);
    call_back(h, type, id, now);
}

static void sm_event(void *ctx, int type, unsigned id, lf_ns now)
{
    /* lf_fap_event values equal the fapx_event_type values. */
    push_event(ctx, type, id, now);
}

static void sm_deliver(void *ctx, uint8_t src, const uint8_t *data, uint16_t len, lf_ns now)
{
    fapx *h = ctx;
    int dropped = 0;
    pthread_mutex_lock(&h->lock);
    lf_fapx_item *it = lf_ring_tail(&h->rx);
    if (it) {
        it->peer = src;
        it->len = len;
        memcpy(it->data, data, len);
        lf_ring_commit(&h->rx);
        set_notify_locked(h);
        if (h->waiters)
            pthread_cond_broadcast(&h->cond);
    } else {
        h->ec.rx_dropped++;
        dropped = 1;
    }
    publish_locked(h);
    pthread_mutex_unlock(&h->lock);
    if (dropped)
        push_event(h, FAPX_EV_RX_OVERFLOW, src, now);
    else
        call_back(h, FAPX_EV_RX, src, now);
}

static int sm_tx_pop(void *ctx, uint8_t *dst, uint8_t *data, uint16_t *len)
{
    fapx *h = ctx;
    int got = 0;
    pthread_mutex_lock(&h->lock);
    lf_fapx_item *it = lf_ring_head(&h->tx);
    if (it) {
        *dst = it->peer;
        *len = it->len;
        memcpy(data, it->data, it->len);
        lf_ring_pop(&h->tx);
        h->tx_inflight = 1;
        got = 1;
        if (h->waiters)                /* room for fapx_tx_wait */
            pthread_cond_broadcast(&h->cond);
    }
    pthread_mutex_unlock(&h->lock);
    return got;
}

static void on_frame(void *ctx, const lf_fap_frame *f, lf_ns now)
{
    fapx *h = ctx;
    lf_trace_emit(&h->trace, FAP_TRACE_RX, FAP_TRACE_OK, now, f->raw, f->raw_len);
    if (h->mode == FAPX_MASTER)
        lf_fap_master_on_frame(&h->m, f, now);
    else
        lf_fap_slave_on_frame(&h->s, f, now);
}

/* Option microseconds -> ns, saturated at LF_FAP_MAX_TIMING_NS (~3 years):
 * a bigger uint64 value would overflow the signed multiply, and deadlines
 * (now + timing) must stay below LF_NEVER. */
#define LF_FAP_MAX_TIMING_NS ((lf_ns)100000000000000000LL)
static lf_ns us_ns(uint64_t us)
{
    return us >= (uint64_t)(LF_FAP_MAX_TIMING_NS / LF_NS_PER_US) ? LF_FAP_MAX_TIMING_NS
                                                                 : (lf_ns)us * LF_NS_PER_US;
}

/* The decoder's rejects, as the trace hook sees them: a candidate frame
 * that failed (bytes skipped while hunting for a marker are noise, not
 * frames, and are not reported). */
static void on_reject(void *ctx, int reason, const uint8_t *raw, size_t len,
                      uint64_t offset, lf_ns now)
{
    fapx *h = ctx;
    (void)offset;
    if (reason == LF_FAP_REJ_GARBAGE)
        return;
    fap_trace_status why = reason == LF_FAP_REJ_CRC ? FAP_TRACE_BAD_CRC
                         : reason == LF_FAP_REJ_GAP ? FAP_TRACE_TRUNCATED
                                                    : FAP_TRACE_BAD_FRAME;
    lf_trace_emit(&h->trace, FAP_TRACE_RX, why, now, raw, len);
}

/* ---- port ---- */

static void port_lost(fapx *h, lf_ns now)
{
    if (h->port_down)
        return;
    h->port_down = 1;
    h->ec.port_lost++;
    h->reopen_at = now + us_ns(h->o.reopen_us);
    lf_fap_decoder_reset(&h->dec);
    push_event(h, FAPX_EV_PORT_LOST, h->id, now);
}

static void try_reopen(fapx *h, lf_ns now)
{
    if (!h->port_down || now < h->reopen_at)
        return;
    if (fap_port_reopen(h->port) == 0 && fap_port_fd(h->port) >= 0) {
        h->port_down = 0;
        h->ec.port_reopened++;
        lf_fap_decoder_reset(&h->dec);
        if (h->mode == FAPX_MASTER)   /* a network server's restart: no 15 s wait */
            lf_fap_master_link_reset(&h->m, now);
        push_event(h, FAPX_EV_PORT_REOPENED, h->id, now);
    } else {
        h->reopen_at = now + us_ns(h->o.reopen_us);
    }
}

static void refresh_port_counts(fapx *h)
{
    fap_port_stats ps;
    fap_port_get_stats(h->port, &ps);
    h->ec.collisions = ps.collisions;
}

/* Transmit the outbox until the state machine stops producing frames, or
 * a stop is requested: a turn can be a second of frames, and a stop must
 * not wait for them (the frames left are counted in tx_abandoned).
 * Returns when the last frame sent ended on the wire (0: none sent). */
static lf_ns drain_outbox(fapx *h)
{
    int wrote_data = 0;
    lf_ns sent_end = 0;
    for (;;) {
        const lf_fap_outbox *o = h->mode == FAPX_MASTER ? &h->m.out : &h->s.out;
        if (o->len == 0)
            break;
        if (lf_fapx_stopping(h)) {
            h->ec.tx_abandoned++;
            pthread_mutex_lock(&h->lock);
            h->tx_abandoned_now = 1;
            pthread_mutex_unlock(&h->lock);
            break;
        }
        lf_ns t_write = lf_now_ns();
        if (!h->port_down) {
            /* A DATA frame is drained (fapx_flush: transmitted); the
             * protocol's own frames only written: no tcdrain per poll. */
            ssize_t r = o->msg == LF_FAP_DATA ? fap_port_write(h->port, o->buf, o->len)
                                              : fap_port_send(h->port, o->buf, o->len);
            if (r == -ECANCELED) {        /* the stop's grace period ran out */
                lf_trace_emit(&h->trace, FAP_TRACE_TX, FAP_TRACE_TX_FAILED, lf_now_ns(),
                              o->buf, o->len);
                h->ec.tx_abandoned++;
                pthread_mutex_lock(&h->lock);
                h->tx_abandoned_now = 1;
                pthread_mutex_unlock(&h->lock);
                break;
            }
            lf_trace_emit(&h->trace, FAP_TRACE_TX,
                          r == (ssize_t)o->len ? FAP_TRACE_OK : FAP_TRACE_TX_FAILED,
                          lf_now_ns(), o->buf, o->len);
            if (r == (ssize_t)o->len || r == FAP_PORT_ECOLLISION) {
                h->ec.frames_tx++;
                h->ec.bytes_tx += o->len;
                if (r == FAP_PORT_ECOLLISION)
                    refresh_port_counts(h);
            } else {
                h->ec.write_errors++;
                if (fap_port_error_is_gone((int)r))
                    port_lost(h, lf_now_ns());
            }
        } else {
            h->ec.write_errors++;          /* the wire is gone: the frame is lost */
        }
        if (o->msg == LF_FAP_DATA)
            wrote_data = 1;
        /* Not drained: the frame ends on the wire no sooner than its wire
         * time after the write began (reply windows start there). */
        lf_ns now = lf_now_ns();
        if (o->msg != LF_FAP_DATA) {
            lf_ns end = t_write + (lf_ns)o->len * lf_char_time_ns(fap_port_baud(h->port));
            if (end > now)
                now = end;
        }
        if (h->mode == FAPX_MASTER)
            lf_fap_master_sent(&h->m, now);
        else
            lf_fap_slave_sent(&h->s, now);
        sent_end = now;
        /* Per frame, not per burst: a peer may already hold this frame, and
         * a slave's turn can be a second of frames. */
        pthread_mutex_lock(&h->lock);
        publish_locked(h);
        pthread_mutex_unlock(&h->lock);
    }
    pthread_mutex_lock(&h->lock);
    if (h->tx_inflight || wrote_data) {
        h->tx_inflight = 0;
        if (h->waiters)
            pthread_cond_broadcast(&h->cond);
    }
    publish_locked(h);
    pthread_mutex_unlock(&h->lock);
    return sent_end;
}

/* Apply the application's slave-list changes (a snapshot taken under the
 * lock) to the master. Not under the lock: the master calls tx_pop. */
static void apply_list(fapx *h, uint32_t want_listed, const uint8_t *epoch, lf_ns now)
{
    for (unsigned id = 1; id <= LF_FAP_MAX_ID; id++) {
        uint32_t bit = 1u << id;
        int want = (want_listed & bit) != 0;
        int have = (h->applied_listed & bit) != 0;
        if (have && (!want || h->applied_epoch[id] != epoch[id])) {
            lf_fap_master_remove(&h->m, id, now);
            h->applied_listed &= ~bit;
            have = 0;
        }
        if (want && !have) {
            lf_fap_master_add(&h->m, id, now);
            h->applied_listed |= bit;
            h->applied_epoch[id] = epoch[id];
        }
    }
}

/* Arm the timerfd for `deadline`. Lazy: a later deadline than the one
 * armed is left alone (the early expiry just re-arms), which saves a
 * syscall per poll cycle while deadlines keep moving out. */
static void arm_timer(fapx *h, lf_ns deadline)
{
    if (deadline == h->armed || (h->armed >= 0 && deadline > h->armed))
        return;
    lf_timerfd_arm_at(h->timer_fd, deadline);
    h->armed = deadline;
}

static lf_ns min_ns(lf_ns a, lf_ns b)
{
    return a < b ? a : b;
}

/* epoll_pwait2 takes a nanosecond timeout: the engine's deadlines need no
 * timerfd_settime (nor a timerfd read) at all. Called as a raw syscall, not
 * through glibc's wrapper (2.35+): the library then runs on an older glibc
 * too (a manylinux_2_34 wheel may not need a newer symbol), and a kernel
 * older than 5.11 answers ENOSYS: the engine falls back to the timerfd. The
 * timeout is the kernel's own 64-bit timespec on every architecture. */
#if defined(SYS_epoll_pwait2)
#define LF_HAVE_EPOLL_PWAIT2 1
static int lf_epoll_pwait2(int ep, struct epoll_event *evs, int n, lf_ns timeout)
{
    struct __kernel_timespec ts, *tp = NULL;
    if (timeout != LF_NEVER) {
        ts.tv_sec = timeout / LF_NS_PER_S;
        ts.tv_nsec = timeout % LF_NS_PER_S;
        tp = &ts;
    }
    return (int)syscall(SYS_epoll_pwait2, ep, evs, n, tp, NULL, (size_t)0);
}
#endif

/* The engine loop's own state (engine thread only). */
typedef struct engine {
    fapx *h;
    int reg_port;                 /* port fd registered in epoll_fd (-1: none) */
    lf_ns hold_until;             /* a frame is arriving: read it then (0: none) */
    unsigned baud;
    lf_rx_link link;              /* the link was seen running at the port's baud */
    lf_rx_plan plan;              /* when to read (port/rx_plan.h); its stage: the
                                     awaited DATA_DONE's hold (asleep for it, or for its rest) */
    lf_ns held_to;                /* when the last hold was due to end (0: none) */
    /* The awaited DATA_DONE (master; reply_predict.h) */
    lf_reply_predict rp;
    unsigned poll_id;             /* the slave polled (0: no reply to learn from) */
    lf_ns poll_sent;              /* when its SEND_DATA ended on the wire */
    uint64_t polls0;              /* m.c.polls then: a DATA_DONE came when it moves */
    uint64_t data0;               /* m.c.data_rx then: the slave sent DATA when it moves */
    uint8_t rbuf[4096];
} engine;

/* Timing, decoder and state machine from the handle's options. */
static void engine_init(engine *e, fapx *h)
{
    lf_ns now = lf_now_ns();
    lf_fap_timing t = {
        .idc = us_ns(h->o.idc_us),
        /* a network transport's round trip on top (port/port_link.h) */
        .id_answer = us_ns(h->o.id_answer_us) + lf_port_link_slack_ns(h->port),
        .data_done = us_ns(h->o.data_done_us),
        .send_budget = us_ns(h->o.send_budget_us),
    };
    lf_fap_io io = { .ctx = h, .tx_pop = sm_tx_pop, .deliver = sm_deliver, .event = sm_event };
    /* default gap: a frame split across TCP segments is still one frame */
    lf_ns gap = h->o.gap_us ? us_ns(h->o.gap_us)
                            : lf_fap_default_gap(fap_port_baud(h->port)) +
                                  lf_port_link_slack_ns(h->port);
    lf_fap_decoder_init(&h->dec, gap);
    lf_fap_decoder_on_reject(&h->dec, on_reject, h);
    if (h->mode == FAPX_MASTER)
        lf_fap_master_init(&h->m, &t, &io, now);
    else
        lf_fap_slave_init(&h->s, h->id, &t, &io);
    h->applied_listed = 0;
    memset(h->applied_epoch, 0, sizeof h->applied_epoch);
    h->armed = -1;
    arm_timer(h, LF_NEVER);
    memset(e, 0, sizeof *e);
    e->h = h;
    e->reg_port = -1;
    e->baud = fap_port_baud(h->port);
    /* a device at a known baud (a network transport paces nothing here) */
    int device = (fap_port_caps(h->port) & FAP_PORT_CAP_PACED) && lf_port_link_slack_ns(h->port) == 0;
    lf_reply_predict_init(&e->rp, e->baud, device);
    /* any hold that finds its frame complete on time clears the belief */
    lf_rx_plan_init(&e->plan, e->baud, &e->link, 1);
}

/* The application's requests (stop, queued data, slave list), under the
 * lock; 1: stop. */
static int take_requests(fapx *h, lf_ns now)
{
    pthread_mutex_lock(&h->lock);
    if (h->stop) {
        pthread_mutex_unlock(&h->lock);
        return 1;
    }
    int kick = h->tx_kick;
    h->tx_kick = 0;
    uint32_t want = h->want_listed;
    uint8_t epoch[32];
    memcpy(epoch, h->add_epoch, sizeof epoch);
    pthread_mutex_unlock(&h->lock);
    if (h->mode == FAPX_MASTER) {
        apply_list(h, want, epoch, now);
        if (kick)
            lf_fap_master_tx_queued(&h->m, now);
    }
    return 0;
}

/* Keep the port fd in epoll_fd: registered once per open (and again after
 * a reopen), never per frame. */
static void watch_port(engine *e)
{
    fapx *h = e->h;
    int want = h->port_down ? -1 : fap_port_fd(h->port);
    if (!h->port_down && want < 0)
        port_lost(h, lf_now_ns());    /* the port layer found it gone */
    if (want == e->reg_port)
        return;
    if (e->reg_port >= 0)
        epoll_ctl(h->epoll_fd, EPOLL_CTL_DEL, e->reg_port, NULL);   /* may be gone: fine */
    struct epoll_event ee = { .events = EPOLLIN, .data.u32 = LF_FAPX_TAG_PORT };
    if (want >= 0 && epoll_ctl(h->epoll_fd, EPOLL_CTL_ADD, want, &ee) < 0 && errno != EEXIST)
        want = -1;                    /* try again next round */
    e->reg_port = want;
}

/* The nearest deadline: state machine, decoder gap, port reopen, hold. */
static lf_ns next_deadline(const engine *e)
{
    const fapx *h = e->h;
    lf_ns dl = h->mode == FAPX_MASTER ? lf_fap_master_deadline(&h->m)
                                      : lf_fap_slave_deadline(&h->s);
    dl = min_ns(dl, lf_fap_decoder_deadline(&h->dec));
    if (h->port_down)
        dl = min_ns(dl, h->reopen_at);
    if (e->hold_until)
        dl = min_ns(dl, e->hold_until);
    return dl;
}

/* Sleep until an fd is ready or the deadline. Holding, the port is not in
 * the set waited on (hold_epoll_fd): the rest of the frame cannot be in
 * before hold_until, so its pieces must not wake us. Returns 1 if the
 * deadline passed, 0 if not, -1 if the wait failed; *port_ev: the port's
 * events. */
static int wait_events(engine *e, lf_ns deadline, uint32_t *port_ev)
{
    fapx *h = e->h;
    int ep = e->hold_until ? h->hold_epoll_fd : h->epoll_fd;
    struct epoll_event evs[3];
    int ne = -1;
#ifdef LF_HAVE_EPOLL_PWAIT2
    if (!h->no_pwait2) {
        lf_ns left = LF_NEVER;
        if (deadline != LF_NEVER) {
            left = deadline - lf_now_ns();
            if (left < 0)
                left = 0;
        }
        ne = lf_epoll_pwait2(ep, evs, 3, left);
        if (ne < 0 && errno == ENOSYS)
            h->no_pwait2 = 1;
    }
    if (h->no_pwait2) {
        arm_timer(h, deadline);
        ne = epoll_wait(ep, evs, 3, -1);
    }
#else
    arm_timer(h, deadline);           /* no epoll_pwait2 in this libc: the timerfd */
    ne = epoll_wait(ep, evs, 3, -1);
#endif
    if (ne < 0) {
        /* EINTR, or ENOMEM under memory pressure: never give up the bus;
         * back off a moment so an error cannot spin */
        if (errno != EINTR)
            lf_sleep_until(lf_now_ns() + LF_NS_PER_MS);
        return -1;
    }
    uint64_t cnt;
    int timer_ev = ne == 0;           /* epoll_pwait2's timeout */
    for (int i = 0; i < ne; i++) {
        if (evs[i].data.u32 == LF_FAPX_TAG_WAKE) {
            if (read(h->wake_fd, &cnt, sizeof cnt) < 0) { /* spurious: nothing to do */ }
        } else if (evs[i].data.u32 == LF_FAPX_TAG_TIMER) {
            if (read(h->timer_fd, &cnt, sizeof cnt) < 0) { /* raced with a re-arm */ }
            h->armed = -1;            /* expired: arm again next time */
            timer_ev = 1;
        } else {
            *port_ev = evs[i].events;
        }
    }
    return timer_ev;
}

/* A piece of `fed` bytes was read, `missing` still due: the planner's
 * hold (port/rx_plan.h), never past the decoder's gap deadline. Once a
 * frame's second piece showed the link running at the port's baud (not
 * faster: a pty, a network, a bus paced above the port's rate), the next
 * frames hold from their first piece at the baud's pace: one wake-up less
 * per frame. A hold that found its frame complete may have overslept (the
 * link got faster, or the wake-up was late): the next frame observes
 * again. Returns when the hold ends, or 0: watch the port. */
static lf_ns hold_end(engine *e, int frame_start, int held, size_t fed, size_t missing,
                       lf_ns now)
{
    lf_rx_piece in = {
        .n = fed, .missing = missing, .first = frame_start, .now = now,
        .slept_to = held ? e->held_to : 0, .deadline = LF_NEVER,
    };
    lf_rx_action a = lf_rx_plan_piece(&e->plan, &in);
    return a.act == LF_RX_SLEEP_UNTIL ? min_ns(a.until, lf_fap_decoder_deadline(&e->h->dec)) : 0;
}

/* A SEND_DATA went (sent_end: its end on the wire): sleep without the
 * port until its DATA_DONE can be complete, if the link's pace allows a
 * prediction (reply_predict.h); never past the reply timeout. */
static void plan_reply(engine *e, lf_ns sent_end)
{
    fapx *h = e->h;
    const lf_fap_master *m = &h->m;
    e->poll_id = 0;
    /* A frame went while a predicted hold was pending (the slave was
     * removed, or its reply timed out with nothing held): that hold is void. */
    if (lf_rx_plan_sent(&e->plan, lf_fap_decoder_missing(&h->dec)))
        e->hold_until = 0;
    if (h->mode != FAPX_MASTER || m->state != LF_M_POLL_WAIT || m->out.len || h->port_down)
        return;
    e->poll_id = m->cur;
    e->poll_sent = sent_end;
    e->polls0 = m->c.polls;
    e->data0 = m->c.data_rx;
    if (e->hold_until || lf_fap_decoder_missing(&h->dec))
        return;
    lf_ns at = lf_reply_predict_when(&e->rp, m->cur, sent_end);
    lf_rx_action a = lf_rx_plan_reply(&e->plan, LF_RX_REPLY_PREDICTED, LF_FAP_OVERHEAD, at,
                                      sent_end, m->wait_deadline);
    if (a.act == LF_RX_SLEEP_UNTIL)
        e->hold_until = a.until;
}

/* The read at the end of a predicted hold (stage ASLEEP) or of the hold
 * for its rest (stage HOLD). ASLEEP tells the predictor how it went, and
 * the planner holds for the missing bytes at the baud's pace when the
 * reply is not in (the slave was late, or sends DATA in its turn);
 * anything else watches the port again (the state machine's timeout stays
 * as it was). */
static void predicted_read(engine *e, lf_rx_reply_stage stage, size_t fed, lf_ns now)
{
    fapx *h = e->h;
    size_t missing = lf_fap_decoder_missing(&h->dec);
    int done = h->m.c.polls != e->polls0;
    if (stage == LF_RX_REPLY_ASLEEP && e->poll_id) {
        /* a DATA frame in the slave's turn: longer than predicted by design */
        int data_turn = h->m.c.data_rx != e->data0 ||
                        (!done && lf_fap_decoder_msg(&h->dec) == LF_FAP_DATA);
        if (data_turn)
            lf_reply_predict_turn(&e->rp, e->poll_id, 1);
        else
            lf_reply_predict_outcome(&e->rp, e->poll_id,
                                     done ? 0 : missing ? missing : LF_FAP_OVERHEAD);
        e->poll_id = 0;
    }
    lf_rx_reply_read in = {
        .got = fed, .want = LF_FAP_OVERHEAD, .missing = missing, .done = done, .now = now,
        .slept_to = e->held_to, .deadline = lf_fap_decoder_deadline(&h->dec),
    };
    e->plan.stage = stage;
    lf_rx_action a = lf_rx_plan_reply_read(&e->plan, LF_RX_REPLY_PREDICTED, &in);
    if (a.act == LF_RX_SLEEP_UNTIL && !h->port_down)
        e->hold_until = a.until;
    else
        e->plan.stage = LF_RX_REPLY_NONE;
}

/* Read what the port has and feed the decoder; then hold while the frame
 * is incomplete: sleep until all but its last byte can be in at the link's
 * observed pace (never past the gap deadline; port/rx_plan.h). A hold
 * that brought nothing means the wire stalled: watch the port again. */
static void read_port(engine *e, uint32_t port_ev, int timer_ev, lf_ns now)
{
    fapx *h = e->h;
    /* A hold ends at its time, or at any timer (state machine, gap): what
     * has arrived is fed before a timeout is judged. */
    int held = e->hold_until && (timer_ev || now >= e->hold_until);
    lf_rx_reply_stage stage = held ? e->plan.stage : LF_RX_REPLY_NONE;
    if (held) {
        e->held_to = e->hold_until;
        e->hold_until = 0;
        e->plan.stage = LF_RX_REPLY_NONE;
        port_ev |= EPOLLIN;
    }
    size_t fed = 0;
    int frame_start = lf_fap_decoder_missing(&h->dec) == 0;   /* for the pace */
    if (port_ev && !h->port_down) {
        for (int rounds = 0; rounds < 4; rounds++) {
            ssize_t n = fap_port_read(h->port, e->rbuf, sizeof e->rbuf, 0);
            if (n > 0) {
                lf_fap_decoder_feed(&h->dec, e->rbuf, (size_t)n, now, on_frame, h);
                fed += (size_t)n;
            }
            /* fap_port_read reports "no data" as 0, never -EAGAIN or -EINTR */
            if (n < 0 || (n == 0 && rounds == 0 && (port_ev & (EPOLLHUP | EPOLLERR))))
                port_lost(h, now);    /* hung up: a 0-byte read would spin */
            if (n < (ssize_t)sizeof e->rbuf)
                break;
        }
    }
    if (stage != LF_RX_REPLY_NONE) {
        predicted_read(e, stage, fed, now);
        return;
    }
    if (e->poll_id && h->mode == FAPX_MASTER && h->m.c.polls != e->polls0) {
        /* a turn with DATA in it: the DATA_DONE's end is no turnaround */
        int data = h->m.c.data_rx != e->data0;
        if (!data)
            lf_reply_predict_observed(&e->rp, e->poll_id, e->poll_sent, now);
        lf_reply_predict_turn(&e->rp, e->poll_id, data);
        e->poll_id = 0;
    }
    if (fed && !h->port_down) {
        e->hold_until = hold_end(e, frame_start, held, fed, lf_fap_decoder_missing(&h->dec), now);
    } else if (h->port_down) {
        e->hold_until = 0;
    }
}

/* After the wait: a lost port out of the set, reopen, gap and state
 * machine timers. */
static void run_timers(engine *e, lf_ns now)
{
    fapx *h = e->h;
    if (h->port_down && e->reg_port >= 0) {
        /* the fd is closed or dead: unregister it now, so a reopened
         * port that gets the same number is registered again */
        epoll_ctl(h->epoll_fd, EPOLL_CTL_DEL, e->reg_port, NULL);
        e->reg_port = -1;
    }
    try_reopen(h, now);
    lf_fap_decoder_tick(&h->dec, now, on_frame, h);
    if (h->mode == FAPX_MASTER && now >= lf_fap_master_deadline(&h->m))
        lf_fap_master_on_timer(&h->m, now);
}

static void engine_finish(engine *e)
{
    fapx *h = e->h;
    if (e->reg_port >= 0)             /* a restarted engine registers it again */
        epoll_ctl(h->epoll_fd, EPOLL_CTL_DEL, e->reg_port, NULL);
    pthread_mutex_lock(&h->lock);
    publish_locked(h);
    h->exited = 1;                    /* lf_fapx_stop's grace wait ends */
    pthread_cond_broadcast(&h->cond);
    pthread_mutex_unlock(&h->lock);
}

/* The engine thread: one turn per wake-up. */
void *lf_fapx_engine_main(void *arg)
{
    fapx *h = arg;
    /* The real-time option (port_rt.c), checked by the open: applied to
     * this thread; a refusal now is counted in the port's rt_refused. */
    (void)fap_port_rt_enter(h->port);
#ifdef PR_SET_TIMERSLACK
    /* A hold's end is wire timing: without this the kernel may defer the
     * wake-up by the default 50 us slack, and a late hold is a late frame. */
    (void)prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
#endif
    engine e;
    engine_init(&e, h);
    while (!take_requests(h, lf_now_ns())) {
        lf_ns sent_end = drain_outbox(h);
        if (sent_end)
            plan_reply(&e, sent_end);
        watch_port(&e);
        uint32_t port_ev = 0;
        int timer_ev = wait_events(&e, next_deadline(&e), &port_ev);
        if (timer_ev < 0)
            continue;
        lf_ns now = lf_now_ns();
        read_port(&e, port_ev, timer_ev, now);
        run_timers(&e, now);
    }
    engine_finish(&e);
    return NULL;
}
