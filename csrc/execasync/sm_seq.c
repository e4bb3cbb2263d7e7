/* Sans-I/O sequence-number logic of the exec async master and slave. */
#include "execasync/sm_seq.h"

#include <errno.h>

void lf_exec_mtx_start(lf_exec_mtx *t, uint8_t node, uint8_t seq,
                       unsigned retries, lf_ns timeout)
{
    t->node = node;
    t->seq = seq;
    t->attempt = 0;
    t->max_attempts = (unsigned long long)retries + 1;
    t->timeout = timeout;
    t->deadline = 0;
    t->last_error = -ETIMEDOUT;
    t->event = LF_EXEC_EV_NONE;
}

void lf_exec_mtx_sent(lf_exec_mtx *t, lf_ns now)
{
    t->attempt++;
    t->deadline = now + t->timeout;
}

static lf_exec_mact retry_or_fail(lf_exec_mtx *t, int error)
{
    t->last_error = error;
    return t->attempt < t->max_attempts ? LF_EXEC_M_SEND : LF_EXEC_M_FAIL;
}

lf_exec_mact lf_exec_mtx_on_frame(lf_exec_mtx *t, const struct execAsyncStateDef *st)
{
    if (st->Status != EXEC_ASYNC_GOOD) {
        /* most likely our reply, damaged: ask again at once, same seq */
        t->event = LF_EXEC_EV_CORRUPT;
        return retry_or_fail(t, -EBADMSG);
    }
    if (st->Node == t->node && st->SeqNo == t->seq) {
        t->event = LF_EXEC_EV_REPLY;
        return LF_EXEC_M_DONE;
    }
    /* a stray or late frame: wait for the one we asked for */
    t->event = LF_EXEC_EV_UNEXPECTED;
    return LF_EXEC_M_WAIT;
}

lf_exec_mact lf_exec_mtx_on_time(lf_exec_mtx *t, lf_ns now)
{
    if (now < t->deadline)
        return LF_EXEC_M_WAIT;
    return retry_or_fail(t, -ETIMEDOUT);
}

void lf_exec_mseq_finish(lf_exec_mseq *m, uint8_t node, uint8_t seq, int ok)
{
    m->next[node] = ok ? lf_exec_seq_next(seq) : 0;
}

lf_exec_sact lf_exec_sseq_classify(const lf_exec_sseq *s, const struct execAsyncStateDef *st)
{
    if (st->Status != EXEC_ASYNC_GOOD)
        return LF_EXEC_S_IGNORE;
    if (st->Node == EXEC_ASYNC_BROADCAST)
        return LF_EXEC_S_BROADCAST;
    if (st->Node != s->node)
        return LF_EXEC_S_IGNORE;
    if (st->SeqNo != 0 && s->have_last && st->SeqNo == s->last_seq)
        return LF_EXEC_S_RESEND;
    return LF_EXEC_S_PROCESS;
}

void lf_exec_sseq_commit(lf_exec_sseq *s, uint8_t seq)
{
    s->have_last = 1;
    s->last_seq = seq;
}

void lf_exec_rwin_shift(lf_exec_rwin *w, size_t n)
{
    w->end = w->end > n ? w->end - n : 0;
}

int lf_exec_rwin_byte(lf_exec_rwin *w, size_t i, int done, int in_frame)
{
    int in_window = i < w->end;
    if (!done) {
        if (in_window && in_frame)
            w->taint = 1;
        return 0;
    }
    int tainted = w->taint || in_window;
    w->taint = in_window && in_frame;
    return tainted;
}

lf_exec_sact lf_exec_sseq_decide(const lf_exec_sseq *s, const struct execAsyncStateDef *st,
                                 int tainted)
{
    lf_exec_sact act = lf_exec_sseq_classify(s, st);
    if (tainted && (act == LF_EXEC_S_PROCESS || act == LF_EXEC_S_RESEND))
        return LF_EXEC_S_WINDOW;
    return act;
}
