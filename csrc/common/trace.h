/* trace.h - the per-handle trace hook behind fap_trace.h (internal).
 * `fn` is read without the lock first, so a handle without a hook pays
 * one atomic load per frame; the call itself runs under `mu`, so after
 * lf_trace_set returns the old hook is not running and never runs again. */
#ifndef LF_TRACE_H
#define LF_TRACE_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#include "fap_trace.h"

typedef struct lf_trace {
    pthread_mutex_t mu;
    fap_trace_fn fn;          /* atomic access (__atomic builtins) */
    void *ctx;
} lf_trace;

void lf_trace_init(lf_trace *t);
void lf_trace_destroy(lf_trace *t);
void lf_trace_set(lf_trace *t, fap_trace_fn fn, void *ctx);

static inline int lf_trace_on(const lf_trace *t)
{
    return __atomic_load_n(&t->fn, __ATOMIC_ACQUIRE) != NULL;
}

/* Call the hook (if any) with one frame. */
void lf_trace_emit(lf_trace *t, fap_trace_dir dir, fap_trace_status status, int64_t t_ns,
                   const uint8_t *data, size_t len);

#endif
