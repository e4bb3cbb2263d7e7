/* The toy protocol's row of the codec table, written the way a protocol
 * writes its own (csrc/<proto>/codec_table.c): a frame is '<', one length
 * byte n (0..8), n data bytes, '>'; anything else is garbage. Its aliases
 * are its own ("toyish"). Built only in tests/c/codec/toy. */
#include <string.h>

#include "fap_codec.h"
#include "common/codec_span.h"

#define TOY_MAX_DATA 8
#define TOY_BAD_END 2                  /* its own reject code: no '>' */

typedef struct toy_state {
    uint8_t buf[TOY_MAX_DATA + 3];
    size_t n;                          /* bytes of the frame held */
    uint64_t pos;                      /* stream offset of the next byte */
} toy_state;

static const char *const toy_fields[] = {"len"};

static void toy_init(void *state, unsigned baud, int64_t gap_ns)
{
    (void)baud;
    (void)gap_ns;
    memset(state, 0, sizeof(toy_state));
}

static void toy_feed(void *state, const uint8_t *p, size_t n, int64_t now_ns,
                     fap_codec_frame_cb on_frame, fap_codec_reject_cb on_reject, void *ctx)
{
    (void)now_ns;
    toy_state *s = state;
    for (size_t i = 0; i < n; i++, s->pos++) {
        uint8_t b = p[i];
        if (s->n == 0) {
            if (b == '<')
                s->buf[s->n++] = b;
            else if (on_reject)
                on_reject(ctx, FAP_CODEC_GARBAGE, &p[i], 1, s->pos);
            continue;
        }
        if (s->n == 1 && b > TOY_MAX_DATA) {
            s->buf[s->n++] = b;
            if (on_reject)
                on_reject(ctx, TOY_BAD_END, s->buf, s->n, s->pos + 1 - s->n);
            s->n = 0;
            continue;
        }
        s->buf[s->n++] = b;
        if (s->n < 2 || s->n < (size_t)s->buf[1] + 3)
            continue;
        uint64_t at = s->pos + 1 - s->n;
        if (b == '>') {
            fap_codec_frame f = {.offset = at, .raw = s->buf, .raw_len = s->n,
                                 .data = s->buf + 2, .data_len = s->buf[1],
                                 .field = {s->buf[1]}};
            if (on_frame)
                on_frame(ctx, &f);
        } else if (on_reject) {
            on_reject(ctx, TOY_BAD_END, s->buf, s->n, at);
        }
        s->n = 0;
    }
}

LF_CODEC_TICK_BY_FEED(toy)

static void toy_finish(void *state, fap_codec_frame_cb on_frame,
                       fap_codec_reject_cb on_reject, void *ctx)
{
    (void)on_frame;
    toy_state *s = state;
    if (s->n && on_reject)
        on_reject(ctx, FAP_CODEC_TRUNCATED, s->buf, s->n, s->pos - s->n);
    s->n = 0;
}

static const char *toy_reject_name(int code)
{
    const char *r = lf_codec_shared_name(code);
    return r ? r : code == TOY_BAD_END ? "end" : "?";
}

static size_t toy_missing(const void *state)
{
    const toy_state *s = state;
    return s->n == 0 ? 0 : s->n == 1 ? 2 : (size_t)s->buf[1] + 3 - s->n;
}

static size_t toy_encode(uint8_t *out, size_t cap, const unsigned *field,
                         const uint8_t *data, size_t len)
{
    if (field[0] != len || len > TOY_MAX_DATA || cap < len + 3 || (len && !data))
        return 0;
    out[0] = '<';
    out[1] = (uint8_t)len;
    if (len)
        memcpy(out + 2, data, len);
    out[len + 2] = '>';
    return len + 3;
}

static const fap_codec row = LF_CODEC_ROW(toy, lf_codec_never, lf_codec_unnamed, TOY_MAX_DATA + 3);
static const char *const aliases[] = {"toyish", NULL};
LF_CODEC_ENTRY(toy, row, aliases);
