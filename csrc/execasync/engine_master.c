/* Exec async master: the thin I/O layer around sm_seq's transaction
 * machine. Sends on the port, feeds received bytes to execAsyncByteIn,
 * lets lf_exec_mtx decide between waiting, resending and giving up.
 * begin_locked/step_locked/finish are the transaction, written once:
 * execMasterTransact loops on them blocking on the fd, execMasterBegin and
 * execMasterStep expose them for an event loop. */
#include "exec_async_engine.h"

#include <errno.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "common/mono_clock.h"
#include "execasync/codec_internal.h"
#include "execasync/sm_seq.h"
#include "execasync/stop_signal.h"
#include "execasync/stats_atomic.h"
#include "port/port_cancel.h"
#include "port/port_net.h"
#include "port/rx_pacing.h"

#define DEFAULT_REPLY_TIMEOUT_US 100000u
#define DEFAULT_RETRIES          3u

struct execMaster {
    fap_port *port;
    pthread_mutex_t lock;            /* one transaction at a time */
    unsigned reply_timeout_us;       /* guarded by lock */
    unsigned retries;
    lf_exec_mseq seq;                /* next seq per node; [255] = broadcast */
    struct execAsyncStateDef rx;
    byte rxbuf[EXEC_ASYNC_MAX_DATA];
    byte txbuf[EXEC_ASYNC_MAX_FRAME];
    execMasterStats stats;           /* updated and read atomically */
    lf_trace trace;                  /* wire trace hook (fap_trace.h) */
    lf_exec_tap tap;                 /* raw bytes of the reply in progress; under lock */
    pthread_cond_t idle;             /* signalled when busy drops to 0 */
    int busy;                        /* a transaction is in flight (t, txlen valid) */
    lf_exec_mtx t;
    word txlen;
    /* the reply wait (port/rx_pacing.h); all under lock */
    lf_exec_flen flen;               /* wire length of the reply in progress */
    struct { uint16_t req, rep; } expect[256];   /* per node: the last request's
                                      * wire length and its reply's */
    lf_rx_link link;                 /* replies came at the baud's pace (rx_plan.h) */
    int fresh;                       /* nothing read since the attempt was sent */
    lf_ns req_end;                   /* when the attempt's request can have ended */
    int stop_fd;                     /* eventfd: execMasterStop ends the port's waits */
    int port_cancel;                 /* the fd the port watches (it keeps &port_cancel):
                                        o->cancel_fd during the open, then stop_fd */
    int stopped;                     /* atomic: execMasterStop was called */
};

void execMasterOptionsInit(execMasterOptions *o)
{
    if (!o)
        return;
    memset(o, 0, sizeof *o);
    o->reply_timeout_us = DEFAULT_REPLY_TIMEOUT_US;
    o->retries = DEFAULT_RETRIES;
}

int execMasterOpen(execMaster **out, const char *path, const fap_port_options *port,
                   const execMasterOptions *o)
{
    if (!out || !path)
        return -EINVAL;
    execMasterOptions defaults;
    execMasterOptionsInit(&defaults);
    if (!o)
        o = &defaults;
    execMaster *m = calloc(1, sizeof *m);
    if (!m)
        return -ENOMEM;
    m->stop_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (m->stop_fd < 0) {
        int e = -errno;
        free(m);
        return e;
    }
    /* the caller's cancel ends the open; then the port is the engine's (the
     * port reads the int at each wait, and nothing else uses it before
     * execMasterOpen returns) */
    m->port_cancel = o->cancel_fd > 0 ? o->cancel_fd : m->stop_fd;
    int err = lf_port_open_cancellable(&m->port, path, port, &m->port_cancel);
    m->port_cancel = m->stop_fd;
    if (err) {
        close(m->stop_fd);
        free(m);
        return err;
    }
    pthread_mutex_init(&m->lock, NULL);
    pthread_cond_init(&m->idle, NULL);
    lf_trace_init(&m->trace);
    m->reply_timeout_us = o->reply_timeout_us ? o->reply_timeout_us : DEFAULT_REPLY_TIMEOUT_US;
    m->retries = o->retries;
    *out = m;
    return 0;
}

int execMasterSetTimeout(execMaster *m, unsigned reply_timeout_us, unsigned retries)
{
    if (!m)
        return -EINVAL;
    pthread_mutex_lock(&m->lock);
    m->reply_timeout_us = reply_timeout_us ? reply_timeout_us : DEFAULT_REPLY_TIMEOUT_US;
    m->retries = retries;
    pthread_mutex_unlock(&m->lock);
    return 0;
}

static void count_frame(execMaster *m, const lf_exec_mtx *t)
{
    LF_STAT_INC(m->stats.rx_frames);
    if (t->event == LF_EXEC_EV_CORRUPT)
        LF_STAT_INC(m->stats.corrupt);
    else if (t->event == LF_EXEC_EV_UNEXPECTED)
        LF_STAT_INC(m->stats.unexpected);
}

/* Send the frame in txbuf again (or the first time). Lock held. */
static int send_attempt(execMaster *m)
{
    lf_exec_mtx *t = &m->t;
    if (t->attempt > 0)
        LF_STAT_INC(m->stats.retries);
    memset(&m->rx, 0, sizeof m->rx);   /* a half reply of the last attempt is void */
    m->flen.cur = 0;
    lf_ns t_write = lf_now_ns();
    lf_exec_tap_abandon(&m->tap, &m->trace, t_write);
    /* Written, not drained (fap_port_send: the port still drains where RTS
     * or echo need it): a request is followed by its reply, no tcdrain per
     * transaction. The reply window starts when the frame can have left,
     * its wire time after the write began, not earlier. */
    ssize_t w = fap_port_send(m->port, m->txbuf, m->txlen);
    lf_ns now = lf_now_ns();
    lf_trace_emit(&m->trace, FAP_TRACE_TX, w == (ssize_t)m->txlen ? FAP_TRACE_OK : FAP_TRACE_TX_FAILED,
                  now, m->txbuf, m->txlen);
    if (w < 0)
        return (int)w;
    LF_STAT_INC(m->stats.tx_frames);
    lf_ns end = t_write + (lf_ns)m->txlen * lf_char_time_ns(fap_port_baud(m->port));
    m->req_end = end > now ? end : now;
    m->fresh = 1;
    lf_exec_mtx_sent(t, m->req_end);
    return 0;
}

/* End the transaction in flight: the one place that moves the sequence
 * number and counts the outcome. Lock held. */
static int finish(execMaster *m, int err, byte *reply, word reply_cap, word *reply_len)
{
    if (err)
        lf_exec_tap_abandon(&m->tap, &m->trace, lf_now_ns());
    /* Never reuse seq (the slave may have processed it and only the replies
     * were lost); after a failure restart the node at 0 (execasync/sm_seq.h). */
    lf_exec_mseq_finish(&m->seq, m->t.node, m->t.seq, err == 0);
    if (!err) {
        LF_STAT_INC(m->stats.replies);
        word len = m->rx.Length;
        if (len > reply_cap) {
            err = -ENOBUFS;
            len = reply_cap;
        }
        if (len)
            memcpy(reply, m->rxbuf, len);
        if (reply_len)
            *reply_len = m->rx.Length;
    } else {
        LF_STAT_INC(m->stats.failures);
        if (reply_len)
            *reply_len = 0;
    }
    m->busy = 0;
    pthread_cond_broadcast(&m->idle);
    return err;
}

/* Flush, encode with the node's sequence number, send. Lock held, not busy. */
static int begin_locked(execMaster *m, byte node, const byte *req, word req_len)
{
    uint8_t seq = m->seq.next[node];
    m->txlen = execAsyncBufferOut(node, (byte *)req, m->txbuf, (byte)req_len, seq);
    /* a network transport's round trip on top (port/port_net.h) */
    lf_exec_mtx_start(&m->t, node, seq, m->retries,
                      (lf_ns)m->reply_timeout_us * LF_NS_PER_US + lf_port_link_slack_ns(m->port));
    m->busy = 1;
    LF_STAT_INC(m->stats.transactions);
    /* Whatever is waiting now came before our request and cannot be its
     * reply; a corrupt leftover would otherwise trigger a needless retry. */
    /* Not fap_port_flush: it also drops output not yet on the wire, e.g. a
     * broadcast sent just before. */
    int err = fap_port_rt_enter(m->port);   /* real-time option: the caller's thread */
    if (!err)
        err = fap_port_discard_input(m->port);
    if (!err)
        err = send_attempt(m);
    return err;
}

/* Read the reply (or what is queued: wait_until 0) in as few wake-ups as
 * the wire allows (port/rx_pacing.h). An exec frame carries no length: the
 * reply is expected as long as the node's last reply to a request of this
 * length, so the first wait of an attempt is one sleep until the request's
 * end plus that reply's wire time (the reply cannot be complete sooner)
 * once the link was seen at the baud's pace. Lock held, busy. */
static ssize_t read_reply(execMaster *m, byte *buf, size_t cap, int64_t wait_until)
{
    size_t expect = m->expect[m->t.node].req == m->txlen ? m->expect[m->t.node].rep : 0;
    size_t want = lf_exec_rx_want(&m->rx, &m->flen, expect);
    int fresh = m->fresh;
    m->fresh = 0;
    if (!wait_until)   /* execMasterStep: what is there, no wait */
        return lf_port_read_paced(m->port, buf, cap, want, 0);
    if (fresh && expect) {
        lf_ns ct = lf_char_time_ns(fap_port_baud(m->port));
        return lf_port_read_reply(m->port, buf, cap, want, m->req_end + (lf_ns)expect * ct,
                                  wait_until, &m->link);
    }
    return lf_port_read_frame_kept(m->port, buf, cap, want, wait_until, &m->link);
}

/* Read what comes until wait_until (0 = only what is queued), decode it,
 * and let sm_seq decide: reply (0), wait more (EXEC_MASTER_MORE), resend
 * (done here, then EXEC_MASTER_MORE) or give up (its error). An error ends
 * nothing here: the caller passes it to finish(). Lock held, busy. */
static int step_locked(execMaster *m, int64_t wait_until)
{
    lf_exec_mtx *t = &m->t;
    byte chunk[128];
    ssize_t r = read_reply(m, chunk, sizeof chunk, wait_until);
    if (r < 0)
        return (int)r;
    /* Decode the whole chunk: a good reply may follow a bad frame. */
    lf_exec_mact act = LF_EXEC_M_WAIT;
    lf_ns now = r > 0 && lf_trace_on(&m->trace) ? lf_now_ns() : 0;
    for (ssize_t i = 0; i < r; i++) {
        int was_in = lf_exec_rx_in_frame(&m->rx);
        int done = lf_exec_byte_in_traced(chunk[i], &m->rx, m->rxbuf, &m->tap, &m->trace, now);
        lf_exec_flen_byte(&m->flen, &m->rx, was_in, done);
        if (!done)
            continue;
        lf_exec_mact a = lf_exec_mtx_on_frame(t, &m->rx);
        count_frame(m, t);
        if (a == LF_EXEC_M_DONE) {
            m->expect[t->node].req = m->txlen;
            m->expect[t->node].rep = (uint16_t)m->flen.last;
            return 0;              /* bytes after the reply: not ours to wait for */
        }
        if (a != LF_EXEC_M_WAIT)
            act = a;
    }
    if (act == LF_EXEC_M_WAIT) {
        act = lf_exec_mtx_on_time(t, lf_now_ns());
        if (act != LF_EXEC_M_WAIT)
            LF_STAT_INC(m->stats.timeouts);
    }
    if (act == LF_EXEC_M_FAIL)
        return t->last_error;
    if (act == LF_EXEC_M_SEND) {
        int err = send_attempt(m);
        if (err)
            return err;
    }
    return EXEC_MASTER_MORE;
}

static int check_transact_args(const execMaster *m, byte node, const byte *req, word req_len)
{
    if (!m || node == 0 || node == EXEC_ASYNC_BROADCAST || (!req && req_len))
        return -EINVAL;
    if (req_len > EXEC_ASYNC_MAX_DATA)
        return -EMSGSIZE;
    if (__atomic_load_n(&m->stopped, __ATOMIC_ACQUIRE))
        return -ECANCELED;
    return 0;
}

int execMasterBegin(execMaster *m, byte node, const byte *req, word req_len,
                    int64_t *deadline_ns)
{
    int err = check_transact_args(m, node, req, req_len);
    if (err)
        return err;
    pthread_mutex_lock(&m->lock);
    if (m->busy) {
        pthread_mutex_unlock(&m->lock);
        return -EBUSY;
    }
    err = begin_locked(m, node, req, req_len);
    if (err)
        finish(m, err, NULL, 0, NULL);
    else if (deadline_ns)
        *deadline_ns = m->t.deadline;
    pthread_mutex_unlock(&m->lock);
    return err;
}

int execMasterStep(execMaster *m, byte *reply, word reply_cap, word *reply_len,
                   int64_t *deadline_ns)
{
    if (!m || (!reply && reply_cap))
        return -EINVAL;
    pthread_mutex_lock(&m->lock);
    if (!m->busy) {
        pthread_mutex_unlock(&m->lock);
        return -EINVAL;
    }
    int rc = step_locked(m, 0);
    if (rc == EXEC_MASTER_MORE) {
        if (deadline_ns)
            *deadline_ns = m->t.deadline;
    } else {
        rc = finish(m, rc, reply, reply_cap, reply_len);
    }
    pthread_mutex_unlock(&m->lock);
    return rc;
}

void execMasterAbort(execMaster *m)
{
    if (!m)
        return;
    pthread_mutex_lock(&m->lock);
    if (m->busy)
        finish(m, -ECANCELED, NULL, 0, NULL);
    pthread_mutex_unlock(&m->lock);
}

int execMasterTransact(execMaster *m, byte node, const byte *req, word req_len,
                       byte *reply, word reply_cap, word *reply_len)
{
    int err = check_transact_args(m, node, req, req_len);
    if (err || (!reply && reply_cap))
        return err ? err : -EINVAL;
    pthread_mutex_lock(&m->lock);
    while (m->busy)                 /* a Begin/Step transaction is in flight */
        pthread_cond_wait(&m->idle, &m->lock);
    err = begin_locked(m, node, req, req_len);
    /* the same step as execMasterStep, but its read waits on the fd until
     * the attempt's deadline instead of returning at once */
    while (!err) {
        err = step_locked(m, m->t.deadline);
        if (err != EXEC_MASTER_MORE)
            break;
        err = 0;
    }
    err = finish(m, err, reply, reply_cap, reply_len);
    pthread_mutex_unlock(&m->lock);
    return err;
}

int execMasterBroadcast(execMaster *m, const byte *data, word len)
{
    if (!m || (!data && len))
        return -EINVAL;
    if (len > EXEC_ASYNC_MAX_DATA)
        return -EMSGSIZE;
    if (__atomic_load_n(&m->stopped, __ATOMIC_ACQUIRE))
        return -ECANCELED;
    pthread_mutex_lock(&m->lock);
    while (m->busy)                 /* txbuf holds a request that may be resent */
        pthread_cond_wait(&m->idle, &m->lock);
    uint8_t seq = m->seq.next[EXEC_ASYNC_BROADCAST];
    word n = execAsyncBufferOut(EXEC_ASYNC_BROADCAST, (byte *)data, m->txbuf, (byte)len, seq);
    m->seq.next[EXEC_ASYNC_BROADCAST] = lf_exec_seq_next(seq);
    ssize_t w = fap_port_rt_enter(m->port);   /* real-time option: the caller's thread */
    if (w == 0)
        w = fap_port_write(m->port, m->txbuf, n);
    lf_trace_emit(&m->trace, FAP_TRACE_TX, w == (ssize_t)n ? FAP_TRACE_OK : FAP_TRACE_TX_FAILED,
                  lf_now_ns(), m->txbuf, n);
    if (w >= 0) {
        LF_STAT_INC(m->stats.broadcasts);
        LF_STAT_INC(m->stats.tx_frames);
    }
    pthread_mutex_unlock(&m->lock);
    return w < 0 ? (int)w : 0;
}

int execMasterNextSeq(execMaster *m, byte node)
{
    if (!m || node == 0)
        return -EINVAL;
    pthread_mutex_lock(&m->lock);
    int seq = m->seq.next[node];
    pthread_mutex_unlock(&m->lock);
    return seq;
}

void execMasterResetSequence(execMaster *m)
{
    if (!m)
        return;
    pthread_mutex_lock(&m->lock);
    memset(&m->seq, 0, sizeof m->seq);
    pthread_mutex_unlock(&m->lock);
}

void execMasterGetStats(execMaster *m, execMasterStats *out)
{
    if (!m || !out)
        return;
    lf_stats_load(out, &m->stats, sizeof *out);
}

fap_port *execMasterPort(execMaster *m)
{
    return m ? m->port : NULL;
}

void execMasterStop(execMaster *m)
{
    if (!m)
        return;
    lf_exec_signal_stop(&m->stopped, m->stop_fd);
}

void execMasterClose(execMaster *m)
{
    if (!m)
        return;
    fap_port_close(m->port);
    close(m->stop_fd);
    pthread_mutex_destroy(&m->lock);
    pthread_cond_destroy(&m->idle);
    lf_trace_destroy(&m->trace);
    free(m);
}

void execMasterSetTrace(execMaster *m, fap_trace_fn fn, void *ctx)
{
    if (m)
        lf_trace_set(&m->trace, fn, ctx);
}
