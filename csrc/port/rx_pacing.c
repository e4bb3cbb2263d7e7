/* rx_pacing.c - read a frame in one wake-up per wire time, not per byte
 * (see rx_pacing.h). */
#include "port/rx_pacing.h"
#include "port/port_internal.h"

#include <stdint.h>

lf_ns lf_rx_hold_ns(unsigned baud, size_t missing)
{
    if (missing < 2 || baud == 0)
        return 0;
    return (lf_ns)(missing - 1) * lf_char_time_ns(baud);
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
