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
    if (missing < 2 || baud == 0)
        return 0;
    lf_ns ct = lf_char_time_ns(baud);
    lf_ns hold = (lf_ns)(missing - 1) * ct - (ct > HOLD_MARGIN_NS ? ct : HOLD_MARGIN_NS);
    return hold >= HOLD_MIN_NS ? hold : 0;
}

ssize_t lf_port_read_paced(fap_port *p, void *buf, size_t n, size_t want,
                           int64_t deadline_ns)
{
    if (!p || (!buf && n))
        return -EINVAL;
    if (want > n)
        want = n;
    ssize_t r = fap_port_read(p, buf, n, deadline_ns);
    if (r <= 0)
        return r;
    size_t got = (size_t)r;
    unsigned baud = fap_port_baud(p);
    while (got < want) {
        lf_ns hold = lf_rx_hold_ns(baud, want - got);
        if (hold == 0)
            break;                    /* the last byte: the caller waits on the fd */
        lf_ns until = lf_now_ns() + hold;
        if (until > deadline_ns)
            until = deadline_ns;
        /* the backend's sleep: a fake backend in the tests records it */
        if (until > lf_now_ns())
            p->be->sleep_until(p->ctx, until);
        r = fap_port_read(p, (uint8_t *)buf + got, n - got, 0);
        if (r <= 0)
            break;                    /* stalled or failed: report what we have */
        got += (size_t)r;
        if (until >= deadline_ns)
            break;
    }
    return (ssize_t)got;
}
