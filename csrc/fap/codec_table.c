/* FAP's row of the codec table (include/fap_codec.h): the engine's own
 * stream decoder (fap/codec.c) with its reject hook. The engine calls
 * lf_fap_decoder_* directly; this is the same decoder. */
#include "fap_codec.h"
#include "common/codec_span.h"
#include "fap/codec.h"

typedef struct fap_state {
    lf_fap_decoder d;
    /* the callbacks of the call in progress (the decoder's hooks take one ctx) */
    fap_codec_frame_cb on_frame;
    fap_codec_reject_cb on_reject;
    void *ctx;
    int truncating;                    /* finish(): a gap reject is a truncated frame */
} fap_state;

static const char *const fap_fields[] = {"msg", "dst", "src"};

static void fap_frame_hook(void *ctx, const lf_fap_frame *lf, lf_ns now)
{
    (void)now;
    fap_state *s = ctx;
    if (!s->on_frame)
        return;
    fap_codec_frame f = {
        .offset = lf->offset, .raw = lf->raw, .raw_len = lf->raw_len,
        .data = lf->data, .data_len = lf->len, .field = {lf->msg, lf->dst, lf->src},
    };
    s->on_frame(s->ctx, &f);
}

static void fap_reject_hook(void *ctx, int reason, const uint8_t *raw, size_t n,
                            uint64_t offset, lf_ns now)
{
    (void)now;
    fap_state *s = ctx;
    if (s->truncating && reason == LF_FAP_REJ_GAP)
        reason = FAP_CODEC_TRUNCATED;
    if (s->on_reject)
        s->on_reject(s->ctx, reason, raw, n, offset);
}

static void fap_bind(fap_state *s, fap_codec_frame_cb on_frame,
                     fap_codec_reject_cb on_reject, void *ctx)
{
    s->on_frame = on_frame;
    s->on_reject = on_reject;
    s->ctx = ctx;
}

static void fap_init(void *state, unsigned baud, int64_t gap_ns)
{
    fap_state *s = state;
    lf_fap_decoder_init(&s->d, gap_ns > 0 ? gap_ns : lf_fap_default_gap(baud));
    lf_fap_decoder_on_reject(&s->d, fap_reject_hook, s);
    fap_bind(s, NULL, NULL, NULL);
    s->truncating = 0;
}

static void fap_feed(void *state, const uint8_t *p, size_t n, int64_t now_ns,
                     fap_codec_frame_cb on_frame, fap_codec_reject_cb on_reject, void *ctx)
{
    fap_state *s = state;
    fap_bind(s, on_frame, on_reject, ctx);
    lf_fap_decoder_feed(&s->d, p, n, now_ns, fap_frame_hook, s);
}

static int64_t fap_deadline(const void *state)
{
    return lf_fap_decoder_deadline(&((const fap_state *)state)->d);
}

static void fap_tick(void *state, int64_t now_ns, fap_codec_frame_cb on_frame,
                     fap_codec_reject_cb on_reject, void *ctx)
{
    fap_state *s = state;
    fap_bind(s, on_frame, on_reject, ctx);
    lf_fap_decoder_tick(&s->d, now_ns, fap_frame_hook, s);
}

static void fap_finish(void *state, fap_codec_frame_cb on_frame,
                       fap_codec_reject_cb on_reject, void *ctx)
{
    fap_state *s = state;
    if (!s->d.n)
        return;
    /* the held candidate as if the line went quiet: its gap reject is a
     * truncated frame, and what followed its first byte is scanned again */
    s->truncating = 1;
    fap_tick(s, lf_fap_decoder_deadline(&s->d), on_frame, on_reject, ctx);
    s->truncating = 0;
}

static const char *fap_reject_name(int code)
{
    return code == FAP_CODEC_TRUNCATED ? "truncated" : lf_fap_reject_name(code);
}

static const char *fap_frame_name(const fap_codec_frame *f)
{
    static const char *const names[] = {
        [LF_FAP_SEND_DATA] = "SEND_DATA", [LF_FAP_DATA] = "DATA", [LF_FAP_DATA_DONE] = "DATA_DONE",
        [LF_FAP_QUERY_ID] = "QUERY_ID", [LF_FAP_ID] = "ID",
    };
    return f && f->field[0] <= LF_FAP_ID ? names[f->field[0]] : NULL;
}

static size_t fap_missing(const void *state)
{
    return lf_fap_decoder_missing(&((const fap_state *)state)->d);
}

static size_t fap_encode(uint8_t *out, size_t cap, const unsigned *field,
                         const uint8_t *data, size_t len)
{
    return lf_fap_encode(out, cap, field[0], field[1], field[2], data, len);
}

static const fap_codec row = LF_CODEC_ROW(fap, fap_deadline, fap_frame_name, LF_FAP_MAX_FRAME);
LF_CODEC_ENTRY(fap, row, NULL);
