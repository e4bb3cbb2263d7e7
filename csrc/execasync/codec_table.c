/* exec async's row of the codec table (include/fap_codec.h): the
 * receiver's execAsyncByteIn, through the monitor scan (lf_exec_scan),
 * with the bytes of each report kept so it carries them. The engines call
 * execAsyncByteIn directly; this is the same decoder. */
#include <string.h>

#include "fap_codec.h"
#include "common/codec_span.h"
#include "execasync/codec_internal.h"

typedef struct exec_state {
    lf_exec_scan sc;
    lf_codec_span span;
} exec_state;

static const char *const exec_fields[] = {"node", "seq"};

static void exec_init(void *state, unsigned baud, int64_t gap_ns)
{
    (void)baud;
    (void)gap_ns;                      /* exec async has no inter-byte gap rule */
    exec_state *s = state;
    lf_exec_scan_init(&s->sc);
    lf_codec_span_init(&s->span, 0);
}

/* Report what the scan's last stop found. */
static void exec_report(exec_state *s, const lf_codec_sink *k)
{
    lf_exec_scan *sc = &s->sc;
    if (sc->st.Status == EXEC_ASYNC_GOOD) {
        fap_codec_frame f = {
            .offset = sc->rep_start, .data = sc->buf, .data_len = sc->st.Length,
            .field = {sc->st.Node, sc->st.SeqNo},
        };
        lf_codec_span_frame(&s->span, &f, sc->rep_end, k);
    } else {
        lf_codec_span_reject(&s->span, sc->rep_start, sc->rep_end, sc->st.Status, k);
    }
}

/* Bytes before this offset start no frame: outside a frame all but a
 * last DLE (DLE STX may start one). */
static uint64_t exec_held_from(const exec_state *s)
{
    const lf_exec_scan *sc = &s->sc;
    if (lf_exec_rx_in_frame(&sc->st))
        return sc->start;
    const lf_codec_span *sp = &s->span;
    int dle = sp->n && sp->base + sp->n == sc->pos && sp->buf[sp->n - 1] == EXEC_ASYNC_DLE;
    return sc->pos - (dle ? 1 : 0);
}

static void exec_feed(void *state, const uint8_t *p, size_t n, int64_t now_ns,
                      fap_codec_frame_cb on_frame, fap_codec_reject_cb on_reject, void *ctx)
{
    (void)now_ns;
    exec_state *s = state;
    const lf_codec_sink k = {on_frame, on_reject, ctx};
    while (n > 0) {
        size_t used = lf_exec_scan_feed(&s->sc, p, n);
        /* while pushing, the last byte is not held yet: keep it too */
        uint64_t keep = lf_exec_rx_in_frame(&s->sc.st) ? s->sc.start : s->sc.pos - 1;
        if (s->sc.st.Status != EXEC_ASYNC_NONE && s->sc.rep_start < keep)
            keep = s->sc.rep_start;           /* the report below still needs its bytes */
        lf_codec_span_push(&s->span, p, used, keep, &k);
        p += used;
        n -= used;
        if (s->sc.st.Status != EXEC_ASYNC_NONE)
            exec_report(s, &k);
    }
    lf_codec_span_garbage(&s->span, exec_held_from(s), &k);
}

LF_CODEC_TICK_BY_FEED(exec)

static void exec_finish(void *state, fap_codec_frame_cb on_frame,
                        fap_codec_reject_cb on_reject, void *ctx)
{
    exec_state *s = state;
    const lf_codec_sink k = {on_frame, on_reject, ctx};
    lf_codec_span_end(&s->span, lf_exec_rx_in_frame(&s->sc.st), s->sc.start, s->sc.pos, &k);
    memset(&s->sc.st, 0, sizeof s->sc.st);
}

static const char *exec_reject_name(int code)
{
    const char *r = lf_codec_shared_name(code);
    if (!r && code > 0 && code < 256)
        r = lf_exec_status_reason(code);
    return r ? r : "?";
}

static size_t exec_missing(const void *state)
{
    return lf_exec_rx_missing(&((const exec_state *)state)->sc.st);
}

static size_t exec_encode(uint8_t *out, size_t cap, const unsigned *field,
                          const uint8_t *data, size_t len)
{
    if (field[0] > 0xFF || field[1] > 0xFF || len > EXEC_ASYNC_MAX_DATA ||
        cap < EXEC_ASYNC_FRAME_SIZE(len) || (len && !data))
        return 0;
    byte raw[EXEC_ASYNC_MAX_DATA];
    if (len)
        memcpy(raw, data, len);
    return execAsyncBufferOut((byte)field[0], raw, out, (byte)len, (byte)field[1]);
}

static const fap_codec row =
    LF_CODEC_ROW(exec, lf_codec_never, lf_codec_unnamed, EXEC_ASYNC_MAX_FRAME);
/* the old spelling, accepted on input */
static const char *const aliases[] = {"execasync", NULL};
LF_CODEC_ENTRY(execasync, row, aliases);
