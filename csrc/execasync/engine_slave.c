/* Exec async slave: the thin I/O layer around sm_seq (the sequence
 * rule and the reply window, "a message that arrives while we transmit").
 * Receives on the port, feeds execAsyncByteIn, calls the application's
 * handler in the serving thread, sends (or resends) the reply. Every wait
 * is the port's (fap_port_read, lf_port_read_frame), and execSlaveStop is
 * the port's interrupt (port/port_cancel.h: the flag) plus the slave's own
 * cancel fd the port watches (the wait): it ends whichever is running. The
 * open is cancellable too (execSlaveOptions.cancel_fd): the port handle does
 * not exist until it returns, so the caller's fd is the one watched then.
 *
 * A frame with a byte in the reply window is dropped (stats.rx_during_tx).
 * Bytes that arrive during the write itself are only seen on a bus that
 * echoes (echo suppression reports FAP_PORT_ECOLLISION, stats.collisions):
 * a pty or a 4-wire line cannot say when a byte came, and guessing from
 * "readable right after the write" misfires when the master answers faster
 * than this thread returns from write(). */
#include "exec_async_engine.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "common/mono_clock.h"
#include "execasync/codec_internal.h"
#include "execasync/sm_seq.h"
#include "execasync/stats_atomic.h"
#include "port/port_cancel.h"
#include "port/rx_pacing.h"

#define PENDING_SIZE 1024

struct execSlave {
    fap_port *port;                    /* interruptible: execSlaveStop */
    int stop_fd;                       /* eventfd: execSlaveStop ends the port's waits */
    int port_cancel;                   /* the fd the port watches (it keeps &port_cancel):
                                          o->cancel_fd during the open, then stop_fd */
    execSlaveHandler handler;
    void *ctx;
    lf_ns turnaround;                  /* the port's turnaround_us, in ns */
    lf_ns last_rx;                     /* when bytes last arrived */
    lf_exec_sseq seq;
    struct execAsyncStateDef rx;
    byte rxbuf[EXEC_ASYNC_MAX_DATA];
    byte reply[EXEC_ASYNC_MAX_DATA];
    byte last_frame[EXEC_ASYNC_MAX_FRAME];   /* the last reply, as sent */
    word last_len;                     /* 0: the last request had no reply */
    byte pending[PENDING_SIZE];        /* received, not decoded yet */
    size_t pos, len;                   /* pending[pos..len) still to decode */
    lf_exec_rwin window;               /* which of pending arrived in the reply window */
    execSlaveStats stats;
    lf_trace trace;                    /* wire trace hook (fap_trace.h) */
    lf_exec_tap tap;                   /* raw bytes of the request in progress */
    lf_exec_flen flen;                 /* wire length: this request, the last */
    lf_rx_link link;                   /* the link keeps the baud's pace (rx_plan.h) */
};

void execSlaveOptionsInit(execSlaveOptions *o)
{
    if (!o)
        return;
    memset(o, 0, sizeof *o);
    o->node = 1;
}

int execSlaveOpen(execSlave **out, const char *path, const fap_port_options *port,
                  const execSlaveOptions *o, execSlaveHandler handler, void *ctx)
{
    if (!out || !path || !handler)
        return -EINVAL;
    execSlaveOptions defaults;
    execSlaveOptionsInit(&defaults);
    if (!o)
        o = &defaults;
    if (o->node < EXEC_ASYNC_NODE_MIN || o->node > EXEC_ASYNC_NODE_MAX)
        return -EINVAL;
    execSlave *s = calloc(1, sizeof *s);
    if (!s)
        return -ENOMEM;
    s->stop_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (s->stop_fd < 0) {
        int e = -errno;
        free(s);
        return e;
    }
    /* a reply the line does not take ends at execSlaveStop too; the open
     * ends on the caller's cancel, then the port is the slave's (the port
     * reads the int at each wait; nothing else uses it before we return) */
    s->port_cancel = o->cancel_fd > 0 ? o->cancel_fd : s->stop_fd;
    int err = lf_port_open_cancellable(&s->port, path, port, &s->port_cancel);
    s->port_cancel = s->stop_fd;
    if (err) {
        close(s->stop_fd);
        free(s);
        return err;
    }
    lf_trace_init(&s->trace);
    s->handler = handler;
    s->ctx = ctx;
    s->turnaround = port ? (lf_ns)port->turnaround_us * LF_NS_PER_US : 0;
    s->seq.node = o->node;
    *out = s;
    return 0;
}

/* Make room at the end of pending (keeps the undecoded bytes). */
static void compact(execSlave *s)
{
    if (s->pos == 0)
        return;
    memmove(s->pending, s->pending + s->pos, s->len - s->pos);
    lf_exec_rwin_shift(&s->window, s->pos);
    s->len -= s->pos;
    s->pos = 0;
}

/* Before answering: wait out the turnaround delay watching the line. Any
 * byte that comes (or came, during the handler) is in the window. */
static void watch_line(execSlave *s)
{
    compact(s);
    lf_ns until = s->last_rx + s->turnaround;
    while (s->len < PENDING_SIZE) {
        /* with input already there, just collect what is readable */
        lf_ns deadline = s->len > s->pos || lf_now_ns() >= until ? 0 : until;
        ssize_t r = lf_port_read_until(s->port, s->pending + s->len, PENDING_SIZE - s->len,
                                       deadline);
        if (r <= 0)
            break;      /* quiet; an error or a stop shows again on the next wait */
        s->len += (size_t)r;
        s->last_rx = lf_now_ns();
    }
    s->window.end = s->len;
}

/* Send the stored reply (the port waits out whatever turnaround is left). */
static int send_last_reply(execSlave *s)
{
    watch_line(s);
    /* counted before the write: once the master has the reply, the count
     * already shows it */
    LF_STAT_INC(s->stats.replies);
    /* not drained (the port still drains for soft RTS or echo): nothing
     * here waits for the last bit, the next wait is for the next request */
    ssize_t w = fap_port_send(s->port, s->last_frame, s->last_len);
    lf_trace_emit(&s->trace, FAP_TRACE_TX,
                  w == (ssize_t)s->last_len ? FAP_TRACE_OK : FAP_TRACE_TX_FAILED,
                  lf_now_ns(), s->last_frame, s->last_len);
    if (w == FAP_PORT_ECOLLISION)
        LF_STAT_INC(s->stats.collisions);   /* someone talked over our reply */
    return w < 0 && w != FAP_PORT_ECOLLISION ? (int)w : 0;
}

/* One decoded frame. Returns 0 to keep serving, EXEC_SLAVE_* when a
 * request was handled, or a negative error. */
static int handle_frame(execSlave *s, int tainted)
{
    LF_STAT_INC(s->stats.rx_frames);
    lf_exec_sact act = lf_exec_sseq_decide(&s->seq, &s->rx, tainted);
    execSlaveRequest req = {
        .node = s->rx.Node, .seq = s->rx.SeqNo, .len = s->rx.Length, .data = s->rxbuf};
    switch (act) {
    case LF_EXEC_S_IGNORE:
        if (s->rx.Status != EXEC_ASYNC_GOOD)
            LF_STAT_INC(s->stats.corrupt);
        else
            LF_STAT_INC(s->stats.ignored);
        return 0;
    case LF_EXEC_S_WINDOW:
        LF_STAT_INC(s->stats.rx_during_tx);   /* not processed, not answered */
        return 0;
    case LF_EXEC_S_BROADCAST:
        LF_STAT_INC(s->stats.broadcasts);
        (void)s->handler(s->ctx, &req, s->reply, EXEC_ASYNC_MAX_DATA);
        return EXEC_SLAVE_BROADCAST;
    case LF_EXEC_S_RESEND:
        LF_STAT_INC(s->stats.resent);
        if (!s->last_len) {
            LF_STAT_INC(s->stats.no_reply);
            return EXEC_SLAVE_RESENT;
        }
        {
            int err = send_last_reply(s);
            return err ? err : EXEC_SLAVE_RESENT;
        }
    case LF_EXEC_S_PROCESS: {
        LF_STAT_INC(s->stats.processed);
        int n = s->handler(s->ctx, &req, s->reply, EXEC_ASYNC_MAX_DATA);
        /* processed now, whatever happens to the reply: a retry must not
         * run the handler again */
        lf_exec_sseq_commit(&s->seq, req.seq);
        s->last_len = 0;
        if (n < 0) {
            LF_STAT_INC(s->stats.no_reply);
            return EXEC_SLAVE_PROCESSED;
        }
        if (n > EXEC_ASYNC_MAX_DATA) {
            LF_STAT_INC(s->stats.no_reply);
            return -EMSGSIZE;   /* handler bug: nothing is sent */
        }
        s->last_len = execAsyncBufferOut(s->seq.node, s->reply, s->last_frame, (byte)n, req.seq);
        int err = send_last_reply(s);
        return err ? err : EXEC_SLAVE_PROCESSED;
    }
    default:
        return 0;
    }
}

/* Wait for input or a stop until deadline. 1: bytes in pending, 0: time is
 * up, negative: error (the port's: a vanished device) or -ECANCELED. */
static int wait_input(execSlave *s, lf_ns deadline)
{
    if (lf_port_interrupted(s->port))
        return -ECANCELED;   /* even with input queued: the read would not wait */
    /* the rest of the frame: one wake-up per wire time, not per byte
     * (port/rx_pacing.h); a stop during that sleep waits at most that long */
    /* The frame carries no length, only a lower bound (lf_exec_rx_missing):
     * a master polling with requests of one size is expected to send the
     * next like the last, so the bytes it still owes (never more than
     * their wire time from the first bytes: lf_port_read_frame) come in one
     * wake-up instead of one per lower bound. */
    size_t want = lf_exec_rx_want(&s->rx, &s->flen, s->flen.last);
    ssize_t r = lf_port_read_frame_kept(s->port, s->pending, PENDING_SIZE, want, deadline,
                                        &s->link);
    if (r <= 0)
        return (int)r;
    s->pos = 0;
    s->len = (size_t)r;
    s->window.end = 0;
    s->last_rx = lf_now_ns();
    return 1;
}

int execSlaveServe(execSlave *s, int timeout_ms)
{
    if (!s)
        return -EINVAL;
    lf_ns deadline = timeout_ms < 0 ? LF_NEVER : lf_now_ns() + (lf_ns)timeout_ms * LF_NS_PER_MS;
    int rt = fap_port_rt_enter(s->port);   /* real-time option: the serving thread */
    if (rt)
        return rt;
    for (;;) {
        if (lf_port_interrupted(s->port))
            return -ECANCELED;
        while (s->pos < s->len) {
            size_t i = s->pos++;
            int was_in = lf_exec_rx_in_frame(&s->rx);
            int done = lf_exec_byte_in_traced(s->pending[i], &s->rx, s->rxbuf, &s->tap,
                                              &s->trace, s->last_rx);
            lf_exec_flen_byte(&s->flen, &s->rx, was_in, done);
            int tainted = lf_exec_rwin_byte(&s->window, i, done, lf_exec_rx_in_frame(&s->rx));
            if (!done)
                continue;
            int r = handle_frame(s, tainted);
            if (r)
                return r;
        }
        s->pos = s->len = s->window.end = 0;
        int r = wait_input(s, deadline);
        if (r <= 0)
            return r;
    }
}

void execSlaveStop(execSlave *s)
{
    if (!s)
        return;
    lf_port_interrupt(s->port);   /* the flag (lf_port_interrupted): async-signal-safe */
    uint64_t one = 1;             /* ... and the wait in progress: one write */
    ssize_t w = write(s->stop_fd, &one, sizeof one);
    (void)w;   /* EAGAIN: already signalled */
}

void execSlaveGetStats(execSlave *s, execSlaveStats *out)
{
    if (s && out)
        lf_stats_load(out, &s->stats, sizeof *out);
}

void execSlaveClose(execSlave *s)
{
    if (!s)
        return;
    fap_port_close(s->port);
    close(s->stop_fd);   /* after the port: it watched it */
    lf_trace_destroy(&s->trace);
    free(s);
}

void execSlaveSetTrace(execSlave *s, fap_trace_fn fn, void *ctx)
{
    if (s)
        lf_trace_set(&s->trace, fn, ctx);
}

fap_port *execSlavePort(execSlave *s)
{
    return s ? s->port : NULL;
}
