#include "fap/ring.h"
#include <errno.h>
#include <stdlib.h>

int lf_ring_init(lf_ring *r, unsigned cap, size_t item)
{
    r->mem = calloc(cap, item);
    r->item = item;
    r->cap = cap;
    r->head = r->count = 0;
    return r->mem ? 0 : -ENOMEM;
}

void lf_ring_free(lf_ring *r)
{
    free(r->mem);
    r->mem = NULL;
    r->cap = r->count = 0;
}

void *lf_ring_tail(lf_ring *r)
{
    if (r->count == r->cap)
        return NULL;
    return r->mem + (size_t)((r->head + r->count) % r->cap) * r->item;
}

void lf_ring_commit(lf_ring *r)
{
    r->count++;
}

void *lf_ring_head(lf_ring *r)
{
    return r->count ? r->mem + (size_t)r->head * r->item : NULL;
}

void lf_ring_pop(lf_ring *r)
{
    if (r->count) {
        r->head = (r->head + 1) % r->cap;
        r->count--;
    }
}
