/* Fixed-capacity FIFO of fixed-size items (no locking: the owner locks). */
#ifndef LF_FAP_RING_H
#define LF_FAP_RING_H
#include <stddef.h>

typedef struct lf_ring {
    unsigned char *mem;
    size_t item;         /* bytes per item */
    unsigned cap, head, count;
} lf_ring;

int   lf_ring_init(lf_ring *r, unsigned cap, size_t item);   /* 0 or -ENOMEM */
void  lf_ring_free(lf_ring *r);
/* Slot for a new item at the tail, or NULL when full; lf_ring_commit adds it. */
void *lf_ring_tail(lf_ring *r);
void  lf_ring_commit(lf_ring *r);
/* Oldest item or NULL; lf_ring_pop removes it. */
void *lf_ring_head(lf_ring *r);
void  lf_ring_pop(lf_ring *r);
#endif
