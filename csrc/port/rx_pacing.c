/* rx_pacing.c - read a frame in one wake-up per wire time, not per byte
 * (see rx_pacing.h). */
#include "port/rx_pacing.h"
#include "port/port_internal.h"

#include <stdint.h>

/* The planner runs on the transport's clock (a fake OS table in the tests
 * runs its own wire clock); deadlines and sleeps are the port's
 * (lf_now_ns). skew: the first less the second, 0 on a real transport. */
static lf_ns clock_skew(const fap_port *p)
{
    return p->be->now ? p->be->now(p->ctx) - lf_now_ns() : 0;
}

/* The transport's clock: a fake OS table in the tests runs its own. */
static lf_ns pace_now(const fap_port *p)
{
    return p->be->now ? p->be->now(p->ctx) : lf_now_ns();
}

/* A port deadline on the planner's clock (0: do not wait, stays 0). */
static lf_ns plan_time(lf_ns t, lf_ns skew)
{
    if (t == 0 || skew == 0)
        return t;
    return skew > 0 && t > LF_NEVER - skew ? LF_NEVER : t + skew;
}

/* The frame's rest, the planner deciding (rx_plan.h): got > 0 bytes are
 * in buf already. */
static ssize_t read_rest(fap_port *p, void *buf, size_t n, size_t got, size_t want,
                         int64_t deadline_ns, lf_rx_link *link)
{
    lf_rx_plan pl;
    lf_rx_plan_init(&pl, fap_port_baud(p), link, 0);
    lf_rx_piece in = {
        .n = got, .missing = want > got ? want - got : 0, .first = 1,
        .now = pace_now(p),
    };
    for (;;) {
        lf_ns skew = clock_skew(p);
        in.deadline = plan_time(deadline_ns, skew);
        lf_rx_action a = lf_rx_plan_piece(&pl, &in);
        if (a.act == LF_RX_COMPLETE || (a.act == LF_RX_WATCH_UNTIL && a.why == LF_RX_LAST))
            break;                    /* LAST: the caller waits on the fd */
        in.slept_to = 0;
        if (a.act == LF_RX_SLEEP_UNTIL) {
            /* the transport's sleep: a fake OS table in the tests records it */
            if (a.until > lf_now_ns() + skew)
                p->be->sleep_until(p->ctx, a.until - skew);
            in.slept_to = a.until;
        }
        /* OBSERVE: the next piece as the fd brings it, to see the pace */
        ssize_t r = fap_port_read(p, (uint8_t *)buf + got, n - got,
                                  a.act == LF_RX_SLEEP_UNTIL ? 0 : deadline_ns);
        if (r <= 0)
            break;                    /* stalled or failed: report what we have */
        got += (size_t)r;
        in.n = (size_t)r;
        in.missing = want > got ? want - got : 0;
        in.first = 0;
        in.now = pace_now(p);
    }
    return (ssize_t)got;
}

/* bound_rest: the rest no longer than its wire time (lf_port_read_frame). */
static ssize_t read_paced(fap_port *p, void *buf, size_t n, size_t want, int64_t deadline_ns,
                          int bound_rest, lf_rx_link *link)
{
    if (!p || (!buf && n))
        return -EINVAL;
    if (want > n)
        want = n;
    ssize_t r = fap_port_read(p, buf, n, deadline_ns);
    if (r <= 0)
        return r;
    int64_t rest = bound_rest ? lf_rx_rest_deadline(lf_char_time_ns(fap_port_baud(p)), want,
                                                    lf_now_ns(), deadline_ns)
                              : deadline_ns;
    return read_rest(p, buf, n, (size_t)r, want, rest, link);
}

ssize_t lf_port_read_paced(fap_port *p, void *buf, size_t n, size_t want,
                           int64_t deadline_ns)
{
    return read_paced(p, buf, n, want, deadline_ns, 0, NULL);
}

ssize_t lf_port_read_frame(fap_port *p, void *buf, size_t n, size_t want,
                           int64_t deadline_ns)
{
    return read_paced(p, buf, n, want, deadline_ns, 1, NULL);
}

ssize_t lf_port_read_frame_kept(fap_port *p, void *buf, size_t n, size_t want,
                                int64_t deadline_ns, lf_rx_link *link)
{
    return read_paced(p, buf, n, want, deadline_ns, 1, link);
}

lf_rx_link *lf_port_rx_link(fap_port *p)
{
    return p ? &p->rx_link : NULL;
}

int64_t lf_port_tx_end_ns(fap_port *p)
{
    return p ? __atomic_load_n(&p->tx_end_ns, __ATOMIC_RELAXED) : 0;
}

ssize_t lf_port_read_reply(fap_port *p, void *buf, size_t n, size_t want, int64_t not_before,
                           int64_t deadline_ns, lf_rx_link *link)
{
    if (!p || (!buf && n) || !link)
        return -EINVAL;
    if (want > n)
        want = n;
    lf_rx_plan pl;
    lf_rx_plan_init(&pl, fap_port_baud(p), link, 0);
    lf_rx_action a = lf_rx_plan_reply(&pl, LF_RX_REPLY_EXPECTED, want, not_before, lf_now_ns(),
                                      deadline_ns);
    if (a.act == LF_RX_SLEEP_UNTIL) {
        p->be->sleep_until(p->ctx, a.until);
        ssize_t r = fap_port_read(p, buf, n, 0);
        if (r < 0)
            return r;
        lf_rx_reply_read in = {
            .got = (size_t)r, .want = want, .now = lf_now_ns(), .slept_to = a.until,
            .deadline = deadline_ns,
        };
        a = lf_rx_plan_reply_read(&pl, LF_RX_REPLY_EXPECTED, &in);
        if (a.act == LF_RX_COMPLETE)
            return r;
        if (a.why == LF_RX_REPLY_REST)
            return read_rest(p, buf, n, (size_t)r, want, a.until, link);
    }
    /* OBSERVE: as any frame, from its first piece on the fd */
    return read_paced(p, buf, n, want, deadline_ns, 1, link);
}

ssize_t lf_port_read_until(fap_port *p, void *buf, size_t n, int64_t deadline_ns)
{
    if (!p || (!buf && n))
        return -EINVAL;
    int64_t coarse = deadline_ns - LF_NS_PER_MS;   /* a poll ending then ends by deadline_ns */
    if (coarse > lf_now_ns()) {
        ssize_t r = fap_port_read(p, buf, n, coarse);
        if (r != 0)
            return r;
    }
    if (deadline_ns > lf_now_ns())
        p->be->sleep_until(p->ctx, deadline_ns);
    return fap_port_read(p, buf, n, 0);
}
