/* trace.c - the per-handle wire trace hook (see trace.h, fap_trace.h). */
#include "common/trace.h"

void lf_trace_init(lf_trace *t)
{
    pthread_mutex_init(&t->mu, NULL);
    t->fn = NULL;
    t->ctx = NULL;
}

void lf_trace_destroy(lf_trace *t)
{
    pthread_mutex_destroy(&t->mu);
}

void lf_trace_set(lf_trace *t, fap_trace_fn fn, void *ctx)
{
    pthread_mutex_lock(&t->mu);
    t->ctx = ctx;
    __atomic_store_n(&t->fn, fn, __ATOMIC_RELEASE);
    pthread_mutex_unlock(&t->mu);
}

void lf_trace_emit(lf_trace *t, fap_trace_dir dir, fap_trace_status status, int64_t t_ns,
                   const uint8_t *data, size_t len)
{
    if (!lf_trace_on(t))
        return;
    pthread_mutex_lock(&t->mu);
    if (t->fn) {
        fap_trace_frame f = {.dir = dir, .status = status, .t_ns = t_ns, .data = data, .len = len};
        t->fn(t->ctx, &f);
    }
    pthread_mutex_unlock(&t->mu);
}

const char *fap_trace_status_name(int status)
{
    switch (status) {
    case FAP_TRACE_OK: return "ok";
    case FAP_TRACE_BAD_CRC: return "bad_crc";
    case FAP_TRACE_BAD_FRAME: return "bad_frame";
    case FAP_TRACE_TRUNCATED: return "truncated";
    case FAP_TRACE_TX_FAILED: return "tx_failed";
    default: return "?";
    }
}
