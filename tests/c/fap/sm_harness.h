/* Test harness for the sans-I/O state machines: a fake tx queue, recorded
 * deliveries and events, and a log of transmitted frames. */
#ifndef FAP_SM_HARNESS_H
#define FAP_SM_HARNESS_H
#include "fap/sm_master.h"
#include "fap/sm_slave.h"
#include "unit.h"
#include <errno.h>

#define H_MAX 512
typedef struct { uint8_t msg, dst, src; uint16_t len; uint8_t data[LF_FAP_MAX_DATA]; lf_ns t; } h_frame;
typedef struct { int type; unsigned id; lf_ns t; } h_event;

typedef struct harness {
    /* tx queue */
    struct { uint8_t dst; uint16_t len; uint8_t data[LF_FAP_MAX_DATA]; } txq[64];
    int tx_head, tx_count;
    /* outputs */
    h_frame sent[H_MAX];
    int nsent;
    h_frame rx[H_MAX];
    int nrx;
    h_event ev[H_MAX];
    int nev;
} harness;

static int h_tx_pop(void *ctx, uint8_t *dst, uint8_t *data, uint16_t *len)
{
    harness *h = ctx;
    if (!h->tx_count)
        return 0;
    *dst = h->txq[h->tx_head].dst;
    *len = h->txq[h->tx_head].len;
    memcpy(data, h->txq[h->tx_head].data, *len);
    h->tx_head = (h->tx_head + 1) % 64;
    h->tx_count--;
    return 1;
}

static void h_deliver(void *ctx, uint8_t src, const uint8_t *data, uint16_t len, lf_ns now)
{
    harness *h = ctx;
    if (h->nrx >= H_MAX)
        return;
    h_frame *f = &h->rx[h->nrx++];
    f->msg = LF_FAP_DATA;
    f->src = src;
    f->len = len;
    memcpy(f->data, data, len);
    f->t = now;
}

static void h_event_cb(void *ctx, int type, unsigned id, lf_ns now)
{
    harness *h = ctx;
    if (h->nev < H_MAX)
        h->ev[h->nev++] = (h_event){ type, id, now };
}

static inline void h_queue(harness *h, unsigned dst, const char *text)
{
    int i = (h->tx_head + h->tx_count) % 64;
    h->txq[i].dst = (uint8_t)dst;
    h->txq[i].len = (uint16_t)strlen(text);
    memcpy(h->txq[i].data, text, h->txq[i].len);
    h->tx_count++;
}

static inline lf_fap_io h_io(harness *h)
{
    return (lf_fap_io){ .ctx = h, .tx_pop = h_tx_pop, .deliver = h_deliver, .event = h_event_cb };
}

/* Decode an outbox (it is a real encoded frame) into the sent log. */
static inline void h_log_outbox(harness *h, const lf_fap_outbox *o, lf_ns now)
{
    if (h->nsent >= H_MAX)
        return;
    h_frame *f = &h->sent[h->nsent++];
    f->msg = o->buf[10];
    f->dst = o->buf[11];
    f->src = o->buf[12];
    f->len = (uint16_t)(o->len - LF_FAP_OVERHEAD);
    memcpy(f->data, o->buf + LF_FAP_HDR_LEN, f->len);
    f->t = now;
}

static inline lf_fap_frame h_frame_of(unsigned msg, unsigned dst, unsigned src, const char *data)
{
    return (lf_fap_frame){ .msg = (uint8_t)msg, .dst = (uint8_t)dst, .src = (uint8_t)src,
                           .len = (uint16_t)(data ? strlen(data) : 0), .data = (const uint8_t *)data };
}
#endif
