/* rx_pacing.c - read a frame in one wake-up per wire time, not per byte
 * (see rx_pacing.h). */
#include "port/rx_pacing.h"
#include "port/port_internal.h"

#include <stdint.h>

/* The hold starts when the engine READ the first bytes, which may be a
 * wake-up latency after they arrived: end it this much early, so a late
 * wake-up does not become a late answer (measured: 50-200 us p50 on a
 * loaded 2-core box). */
#define HOLD_MARGIN_NS (150 * LF_NS_PER_US)
/* A shorter sleep costs more (timer, epoll changes) than the wake-ups it
 * saves: at 1 Mbaud a short frame comes in one or two pieces anyway. */
#define HOLD_MIN_NS (100 * LF_NS_PER_US)

lf_ns lf_rx_hold_ns(unsigned baud, size_t missing)
{
    return baud ? lf_rx_hold_ct_ns(lf_char_time_ns(baud), missing) : 0;
}

lf_ns lf_rx_hold_ct_ns(lf_ns ct, size_t missing)
{
    if (missing < 2 || ct <= 0)
        return 0;
    lf_ns hold = (lf_ns)(missing - 1) * ct - (ct > HOLD_MARGIN_NS ? ct : HOLD_MARGIN_NS);
    return hold >= HOLD_MIN_NS ? hold : 0;
}

int lf_rx_at_baud(lf_ns gap, lf_ns ct, size_t n)
{
    return gap * 10 >= ct * 7 * (lf_ns)n;
}

lf_ns lf_rx_pace_hold(lf_rx_pace *s, unsigned baud, int first, size_t n, size_t missing,
                      lf_ns now)
{
    lf_ns last = s->t_last;
    s->t_last = missing ? now : 0;
    if (first || last <= 0 || n == 0 || missing == 0)
        return 0;                     /* nothing observed yet: wait for the next piece */
    lf_ns seen = (now - last) / (lf_ns)n;
    if (seen < 1)
        seen = 1;
    lf_ns ct = baud ? lf_char_time_ns(baud) : seen;
    return lf_rx_hold_ct_ns(seen < ct ? seen : ct, missing);
}

/* The transport's clock: a fake OS table in the tests runs its own. */
static lf_ns pace_now(const fap_port *p)
{
    return p->be->now ? p->be->now(p->ctx) : lf_now_ns();
}

/* Steps 2-4 of lf_port_read_paced: got > 0 bytes are in buf already. */
static ssize_t read_rest(fap_port *p, void *buf, size_t n, size_t got, size_t want,
                         int64_t deadline_ns, int *at_baud)
{
    unsigned baud = fap_port_baud(p);
    lf_ns ct = lf_char_time_ns(baud);
    lf_rx_pace pace = {0};
    lf_ns t0 = pace_now(p);
    lf_ns hold = lf_rx_pace_hold(&pace, baud, 1, got, want > got ? want - got : 0, t0);
    int observed = 0, trusted = 0;
    if (at_baud && *at_baud && ct > 0) {
        /* the last frame showed the link at the baud: hold from here */
        hold = lf_rx_hold_ct_ns(ct, want > got ? want - got : 0);
        observed = trusted = 1;
        pace.t_last = t0;
    }
    while (got < want) {
        lf_ns until = deadline_ns;
        if (observed) {
            if (hold == 0)
                break;                /* the last byte: the caller waits on the fd */
            until = lf_now_ns() + hold;
            if (until > deadline_ns)
                until = deadline_ns;
            /* the transport's sleep: a fake OS table in the tests records it */
            if (until > lf_now_ns())
                p->be->sleep_until(p->ctx, until);
        }
        /* the first time: the next piece as the fd brings it, to see the pace */
        lf_ns last = pace.t_last;
        ssize_t r = fap_port_read(p, (uint8_t *)buf + got, n - got, observed ? 0 : deadline_ns);
        if (r <= 0)
            break;                    /* stalled or failed: report what we have */
        got += (size_t)r;
        lf_ns now = pace_now(p);
        if (at_baud && !observed && last > 0 && ct > 0)   /* a piece as the wire brought it */
            *at_baud = lf_rx_at_baud(now - last, ct, (size_t)r);
        else if (at_baud && trusted && got >= want && lf_now_ns() - until <= ct)
            *at_baud = 0;             /* all in at a hold that woke on time (the
                                       * sleep's clock): the link may be faster */
        hold = lf_rx_pace_hold(&pace, baud, 0, (size_t)r, want > got ? want - got : 0, now);
        if (observed && until >= deadline_ns)
            break;
        observed = 1;
    }
    return (ssize_t)got;
}

/* bound_rest: the rest no longer than its wire time (lf_port_read_frame). */
static ssize_t read_paced(fap_port *p, void *buf, size_t n, size_t want, int64_t deadline_ns,
                          int bound_rest, int *at_baud)
{
    if (!p || (!buf && n))
        return -EINVAL;
    if (want > n)
        want = n;
    ssize_t r = fap_port_read(p, buf, n, deadline_ns);
    if (r <= 0)
        return r;
    int64_t rest = bound_rest ? lf_now_ns() + (int64_t)want * lf_char_time_ns(fap_port_baud(p))
                              : deadline_ns;
    return read_rest(p, buf, n, (size_t)r, want, rest < deadline_ns ? rest : deadline_ns,
                     at_baud);
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
                                int64_t deadline_ns, int *at_baud)
{
    return read_paced(p, buf, n, want, deadline_ns, 1, at_baud);
}

int *lf_port_rx_at_baud(fap_port *p)
{
    return p ? &p->rx_at_baud : NULL;
}

int64_t lf_port_tx_end_ns(fap_port *p)
{
    return p ? __atomic_load_n(&p->tx_end_ns, __ATOMIC_RELAXED) : 0;
}

ssize_t lf_port_read_reply(fap_port *p, void *buf, size_t n, size_t want, int64_t not_before,
                           int64_t deadline_ns, int *at_baud)
{
    if (!p || (!buf && n) || !at_baud)
        return -EINVAL;
    if (want > n)
        want = n;
    lf_ns ct = lf_char_time_ns(fap_port_baud(p));
    lf_ns now = lf_now_ns();
    /* a reply shorter than a hold is worth (lf_rx_hold_ct_ns: a short frame
     * at 1 Mbaud) comes in a piece or two anyway: no sleep for it */
    if (*at_baud && lf_rx_hold_ct_ns(ct, want) > 0 && not_before > now && deadline_ns > now) {
        /* the reply cannot be complete before not_before: one sleep, one read */
        lf_ns until = not_before < deadline_ns ? not_before : deadline_ns;
        p->be->sleep_until(p->ctx, until);
        ssize_t r = fap_port_read(p, buf, n, 0);
        if (r < 0)
            return r;
        if (until == deadline_ns)
            return r;           /* the deadline came first: what is in */
        if (r > 0 && (size_t)r >= want) {
            if (lf_now_ns() - until <= ct)
                *at_baud = 0;   /* complete at an on-time wake: the link is faster */
            return r;
        }
        if (r > 0) {   /* the rest at the baud's pace, bounded by its wire time */
            int64_t rest = lf_now_ns() + (int64_t)(want - (size_t)r) * ct;
            return read_rest(p, buf, n, (size_t)r, want, rest < deadline_ns ? rest : deadline_ns,
                             at_baud);
        }
        /* nothing yet (a slow responder): wait for it on the fd as before */
    }
    return read_paced(p, buf, n, want, deadline_ns, 1, at_baud);
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
