/* Held stream bytes of the span-reporting codecs. See codec_span.h. */
#include "common/codec_span.h"

#include <string.h>

void lf_codec_span_init(lf_codec_span *s, uint64_t base)
{
    s->base = base;
    s->n = 0;
}

/* Forget the held bytes before offset `to` (already reported). */
static void drop_to(lf_codec_span *s, uint64_t to)
{
    if (to <= s->base)
        return;
    size_t k = to - s->base < s->n ? (size_t)(to - s->base) : s->n;
    memmove(s->buf, s->buf + k, s->n - k);
    s->n -= k;
    s->base += k;
}

void lf_codec_span_garbage(lf_codec_span *s, uint64_t upto, const lf_codec_sink *k)
{
    if (upto <= s->base)
        return;
    size_t n = upto - s->base < s->n ? (size_t)(upto - s->base) : s->n;
    if (k->on_reject)
        k->on_reject(k->ctx, FAP_CODEC_GARBAGE, s->buf, n, s->base);
    drop_to(s, s->base + n);
}

void lf_codec_span_push(lf_codec_span *s, const uint8_t *p, size_t n, uint64_t free_before,
                        const lf_codec_sink *k)
{
    for (size_t i = 0; i < n; i++) {
        if (s->n == sizeof s->buf) {
            lf_codec_span_garbage(s, free_before, k);
            if (s->n == sizeof s->buf)      /* longer than any span: never, by the bound */
                lf_codec_span_garbage(s, s->base + s->n / 2, k);
        }
        s->buf[s->n++] = p[i];
    }
}

/* [start, end) clipped to the held bytes, after reporting the garbage before it. */
static size_t span_at(lf_codec_span *s, uint64_t *start, uint64_t end, const lf_codec_sink *k)
{
    lf_codec_span_garbage(s, *start, k);
    if (*start < s->base)
        *start = s->base;
    uint64_t held_end = s->base + s->n;
    if (end > held_end)
        end = held_end;
    return end > *start ? (size_t)(end - *start) : 0;
}

void lf_codec_span_reject(lf_codec_span *s, uint64_t start, uint64_t end, int code,
                          const lf_codec_sink *k)
{
    size_t n = span_at(s, &start, end, k);
    if (k->on_reject && n)
        k->on_reject(k->ctx, code, s->buf + (start - s->base), n, start);
    drop_to(s, start + n);
}

void lf_codec_span_end(lf_codec_span *s, int in_frame, uint64_t start, uint64_t pos,
                       const lf_codec_sink *k)
{
    if (in_frame)
        lf_codec_span_reject(s, start, pos, FAP_CODEC_TRUNCATED, k);
    lf_codec_span_garbage(s, pos, k);
}

int64_t lf_codec_never(const void *state)
{
    (void)state;
    return FAP_CODEC_NEVER;
}

const char *lf_codec_unnamed(const fap_codec_frame *f)
{
    (void)f;
    return NULL;
}

const char *lf_codec_shared_name(int code)
{
    return code == FAP_CODEC_GARBAGE ? "garbage" : code == FAP_CODEC_TRUNCATED ? "truncated" : NULL;
}

void lf_codec_span_frame(lf_codec_span *s, fap_codec_frame *f, uint64_t end,
                         const lf_codec_sink *k)
{
    uint64_t start = f->offset;
    size_t n = span_at(s, &start, end, k);
    f->offset = start;
    f->raw = s->buf + (start - s->base);
    f->raw_len = n;
    if (k->on_frame)
        k->on_frame(k->ctx, f);
    drop_to(s, start + n);
}
