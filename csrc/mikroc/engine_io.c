/* mikroC RS-485 node on a fap_port: Send writes a frame, Receive/Poll read
 * bytes and feed the sans-I/O node (mikroc/sm_node.c). */
#include <errno.h>
#include <stdint.h>

#include "mikroc_rs485.h"
#include "mikroc/mikroc_internal.h"
#include "port/rx_pacing.h"

int mikrocRS485_CtxBind(mikrocRS485_ctx *c, fap_port *port)
{
    if (c->owns_port && c->port != port) {
        fap_port_close(c->port);   /* re-binding drops a port we opened */
        c->owns_port = 0;
    }
    c->port = port;
    c->rx_pos = c->rx_len = 0;
    return 0;
}

int lf_mikroc_port_open(fap_port **out, const char *path, unsigned baud,
                        const fap_port_options *opts)
{
    fap_port_options o;
    if (opts)
        o = *opts;
    else
        fap_port_options_init(&o);
    if (baud)
        o.baud = baud;
    return fap_port_open(out, path, &o);
}

int mikrocRS485_CtxOpen(mikrocRS485_ctx *c, const char *path, unsigned baud,
                        const fap_port_options *opts)
{
    if (!path)
        return -EINVAL;
    if (c->owns_port)
        return -EBUSY;
    fap_port *p = NULL;
    int r = lf_mikroc_port_open(&p, path, baud, opts);
    if (r < 0)
        return r;
    mikrocRS485_CtxBind(c, p);
    c->owns_port = 1;
    return 0;
}

void mikrocRS485_CtxClose(mikrocRS485_ctx *c)
{
    mikrocRS485_CtxBind(c, NULL);     /* closes the port if we opened it */
}

int mikrocRS485_CtxResetRx(mikrocRS485_ctx *c)
{
    mikrocRS485_DecoderInit(&c->dec);
    c->rx_pos = c->rx_len = 0;
    if (!c->port)
        return 0;
    /* Read the stale input away rather than fap_port_flush(): that also
     * drops output not yet on the wire (a pty's tcdrain does not wait), and
     * our previous frame may still be in it. Bounded: a bus that never goes
     * quiet cannot keep us here. */
    uint8_t junk[64];
    for (int i = 0; i < 64; i++) {
        ssize_t n = fap_port_read(c->port, junk, sizeof junk, 0);
        if (n <= 0)
            return n < 0 ? (int)n : 0;
    }
    return 0;
}

/* Refill the read-ahead buffer with up to max bytes: >0 bytes, 0 nothing by
 * the deadline, <0 error. not_before: the frame cannot be complete sooner
 * (0: unknown). */
static int refill(mikrocRS485_ctx *c, size_t max, size_t want, int64_t not_before,
                  int64_t deadline_ns)
{
    /* the caller's thread does the I/O: the real-time option applies to it */
    ssize_t n = fap_port_rt_enter(c->port);
    /* want > 1: the frame's wire time in one sleep, not a wake-up per byte,
     * at the pace the last frame showed (the port keeps it) */
    if (n == 0 && not_before)
        n = lf_port_read_reply(c->port, c->rx, max, want, not_before, deadline_ns,
                               lf_port_rx_link(c->port));
    else if (n == 0)
        n = want > 1 ? lf_port_read_frame_kept(c->port, c->rx, max, want, deadline_ns,
                                               lf_port_rx_link(c->port))
                     : fap_port_read(c->port, c->rx, max, deadline_ns);
    if (n < 0) {
        c->stats.last_rx_error = (int)n;
        return (int)n;
    }
    c->rx_pos = 0;
    c->rx_len = (uint16_t)n;
    return (int)n;
}

/* A master waiting for a reply: a slave answers after our frame, so its
 * reply (a full frame expected) cannot be complete before our frame's end
 * plus that frame's wire time (0: no such bound, e.g. a frame started). */
static int64_t reply_not_before(const mikrocRS485_ctx *c)
{
    if (c->role != MIKROC_RS485_ROLE_MASTER || c->dec.in_frame)
        return 0;
    int64_t end = lf_port_tx_end_ns(c->port);
    return end ? end + (int64_t)MIKROC_RS485_FRAME_MAX * lf_char_time_ns(fap_port_baud(c->port))
               : 0;
}

static void feed_one(mikrocRS485_ctx *c, char *data_buffer)
{
    mikrocRS485_CtxReceiveByte(c, data_buffer, c->rx[c->rx_pos++]);
}

void mikrocRS485_CtxReceive(mikrocRS485_ctx *c, char *data_buffer)
{
    if (!c->port || c->role == MIKROC_RS485_ROLE_NONE || !data_buffer)
        return;
    /* One byte per call, like the UART data register: a byte still in the
     * kernel keeps the fd readable, so poll() on fap_port_fd() says when to
     * call again. */
    if (c->rx_pos == c->rx_len && refill(c, 1, 1, 0, 0) <= 0)
        return;                      /* no byte in the "UART register" */
    feed_one(c, data_buffer);
}

static int flags_of(const char *buf)
{
    int m = 0;
    if ((uint8_t)buf[MIKROC_RS485_IDX_READY] == MIKROC_RS485_FLAG_SET)
        m |= MIKROC_RS485_POLL_READY;
    if ((uint8_t)buf[MIKROC_RS485_IDX_ERROR] == MIKROC_RS485_FLAG_SET)
        m |= MIKROC_RS485_POLL_ERROR;
    return m;
}

int mikrocRS485_CtxPoll(mikrocRS485_ctx *c, char *data_buffer, int timeout_ms)
{
    if (c->role == MIKROC_RS485_ROLE_NONE)
        return -EPERM;
    if (!data_buffer)
        return -EINVAL;
    if (!c->port)
        return -ENOTCONN;
    int64_t deadline;
    if (timeout_ms < 0)
        deadline = INT64_MAX;
    else if (timeout_ms == 0)
        deadline = 0;                /* fap_port_read: do not wait */
    else
        deadline = fap_port_now_ns() + (int64_t)timeout_ms * 1000000;
    for (;;) {
        int m = flags_of(data_buffer);
        if (m)
            return m;
        if (c->rx_pos < c->rx_len) {
            feed_one(c, data_buffer);   /* one byte at a time: stop at frame end */
            continue;
        }
        /* a bus that never goes quiet must not hold us past the deadline */
        if (deadline != 0 && deadline != INT64_MAX && fap_port_now_ns() >= deadline)
            return 0;
        int n = refill(c, sizeof c->rx, lf_mikroc_expect(&c->dec), reply_not_before(c),
                       deadline);
        if (n <= 0)
            return n;                /* 0: deadline passed */
    }
}

int mikrocRS485_CtxSend(mikrocRS485_ctx *c, const char *data_buffer,
                        unsigned datalen, uint8_t address)
{
    int r;
    uint8_t frame[MIKROC_RS485_FRAME_MAX];
    if (c->role == MIKROC_RS485_ROLE_NONE) {
        r = -EPERM;
    } else if (datalen > MIKROC_RS485_MAX_DATA || (datalen && !data_buffer)) {
        r = -EINVAL;                 /* rejected, not clamped: nothing is sent */
    } else if (!c->port) {
        r = -ENOTCONN;
    } else {
        int master = c->role == MIKROC_RS485_ROLE_MASTER;
        int n = mikrocRS485_Encode(frame, (const uint8_t *)data_buffer, datalen,
                                   master ? address : c->address, master);
        ssize_t w = n < 0 ? n : fap_port_rt_enter(c->port);   /* real-time: this thread */
        if (w == 0)
            w = fap_port_write(c->port, frame, (size_t)n);
        r = w < 0 ? (int)w : 0;
        if (c->trace && n > 0)
            lf_mikroc_trace(c, FAP_TRACE_TX, w == n ? FAP_TRACE_OK : FAP_TRACE_TX_FAILED,
                            frame, (size_t)n);
    }
    c->stats.last_send_error = r;
    return r;
}
