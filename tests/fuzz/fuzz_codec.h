/* Shared by the decoder fuzz targets: the input decoded through a row of
 * the codec table (include/fap_codec.h), whole and in chunks (seeded),
 * with the properties every row keeps: the same frames and rejects in the
 * same order whatever the chunking, reports in stream order inside the
 * input, each frame's raw bytes the input's bytes at its offset, and (for
 * rows whose reports tile the stream) every byte in exactly one report. */
#ifndef LF_FUZZ_CODEC_H
#define LF_FUZZ_CODEC_H
#include "fuzz_util.h"
#include "fap_codec.h"

#define FZC_MAX 512
typedef struct fzc_ev {
    int code;                   /* 0 a frame, else the reject code */
    uint64_t offset;
    size_t len;
    unsigned field[FAP_CODEC_MAX_FIELDS];
    size_t data_len;
    uint8_t data[1040];         /* a frame's payload (FAP: up to 1024) */
} fzc_ev;

typedef struct fzc_log {
    const uint8_t *input;
    size_t input_len;
    int tiles;                  /* the row's reports must tile the stream */
    uint64_t covered;           /* end of the last report */
    uint64_t last_start;        /* offset of the last good frame */
    int n;                      /* frames and non-garbage rejects (all, even past FZC_MAX) */
    fzc_ev ev[FZC_MAX];
} fzc_log;

static void fzc_span(fzc_log *l, uint64_t off, size_t len, const uint8_t *raw)
{
    PROPERTY(off + len <= l->input_len);
    PROPERTY(len > 0 && !memcmp(raw, l->input + off, len));
    if (l->tiles)
        PROPERTY(off == l->covered);
    l->covered = off + len;
}

static void fzc_frame(void *ctx, const fap_codec_frame *f)
{
    fzc_log *l = ctx;
    fzc_span(l, f->offset, f->raw_len, f->raw);
    PROPERTY(f->offset >= l->last_start);       /* frames come in stream order */
    l->last_start = f->offset;
    PROPERTY(f->data_len <= sizeof l->ev[0].data && f->data_len <= f->raw_len);
    if (l->n < FZC_MAX) {
        fzc_ev *e = &l->ev[l->n];
        e->code = 0;
        e->offset = f->offset;
        e->len = f->raw_len;
        memcpy(e->field, f->field, sizeof e->field);
        e->data_len = f->data_len;
        memcpy(e->data, f->data, f->data_len);
    }
    l->n++;
}

static void fzc_reject(void *ctx, int code, const uint8_t *raw, size_t n, uint64_t offset)
{
    fzc_log *l = ctx;
    fzc_span(l, offset, n, raw);
    PROPERTY(code != 0);
    if (code == FAP_CODEC_GARBAGE)              /* its runs depend on the chunking */
        return;
    if (l->n < FZC_MAX) {
        fzc_ev *e = &l->ev[l->n];
        memset(e, 0, sizeof *e - sizeof e->data);
        e->code = code;
        e->offset = offset;
        e->len = n;
    }
    l->n++;
}

/* Decode p through row c in chunks drawn from seed (0: all at once), with
 * an idle tick before the gap after each chunk, then finish. */
static void fzc_decode(const fap_codec *c, const uint8_t *p, size_t n, unsigned seed,
                       int tiles, fzc_log *l)
{
    l->input = p;
    l->input_len = n;
    l->tiles = tiles;
    l->covered = l->last_start = 0;
    l->n = 0;
    static uint8_t state[1 << 14];
    PROPERTY(c->state_size <= sizeof state);
    c->init(state, 0, 1000);
    size_t pos = 0;
    unsigned x = seed | 1u;
    while (pos < n) {
        size_t k = n - pos;
        if (seed) {
            x = x * 1103515245u + 12345u;
            k = 1 + (x >> 16) % 64;
            if (k > n - pos)
                k = n - pos;
        }
        c->feed(state, p + pos, k, 1, fzc_frame, fzc_reject, l);
        PROPERTY(c->deadline(state) == FAP_CODEC_NEVER || c->deadline(state) == 1001);
        c->tick(state, 2, fzc_frame, fzc_reject, l);   /* before the gap: nothing expires */
        pos += k;
    }
    c->finish(state, fzc_frame, fzc_reject, l);
    PROPERTY(c->deadline(state) == FAP_CODEC_NEVER);
    if (tiles)
        PROPERTY(l->covered == n);
    for (int i = 0; i < l->n && i < FZC_MAX; i++)
        PROPERTY(l->ev[i].code == 0 || strcmp(c->reject_name(l->ev[i].code), "?") != 0);
}

/* The same frames and rejects, whole and chunked. */
static void fzc_same(const fzc_log *a, const fzc_log *b)
{
    PROPERTY(a->n == b->n);
    for (int i = 0; i < a->n && i < FZC_MAX; i++) {
        const fzc_ev *x = &a->ev[i], *y = &b->ev[i];
        PROPERTY(x->code == y->code && x->offset == y->offset && x->len == y->len &&
                 !memcmp(x->field, y->field, sizeof x->field) && x->data_len == y->data_len &&
                 !memcmp(x->data, y->data, x->data_len));
    }
}
#endif
