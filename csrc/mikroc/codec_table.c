/* mikroC RS-485's row of the codec table (include/fap_codec.h): the
 * receiver's mikrocRS485_DecoderFeed, through the monitor scan
 * (lf_mikroc_scan), with the bytes of each report kept so it carries
 * them. The receive paths call the decoder directly; this is the same one. */
#include <string.h>

#include "fap_codec.h"
#include "common/codec_span.h"
#include "mikroc/mikroc_internal.h"
#include "mikroc/codec.h"

typedef struct mikroc_state {
    lf_mikroc_scan sc;
    lf_codec_span span;
} mikroc_state;

static const char *const mikroc_fields[] = {"address", "from_master"};

/* The scan's short reasons, in code order from 2 (1 is garbage). */
static const char *const mikroc_reasons[] = {"crc", "datalen", "escape", "short", "long", "abort"};
#define N_REASONS (sizeof mikroc_reasons / sizeof mikroc_reasons[0])

static void mikroc_init(void *state, unsigned baud, int64_t gap_ns)
{
    (void)baud;
    (void)gap_ns;                      /* the mikroC receiver has no gap rule */
    mikroc_state *s = state;
    lf_mikroc_scan_init(&s->sc);
    lf_codec_span_init(&s->span, 0);
}

static int mikroc_code(const char *reason)
{
    for (size_t i = 0; reason && i < N_REASONS; i++)
        if (strcmp(reason, mikroc_reasons[i]) == 0)
            return (int)i + 2;
    return 0;
}

static void mikroc_report(mikroc_state *s, const lf_codec_sink *k)
{
    lf_mikroc_scan *sc = &s->sc;
    if (sc->code == MIKROC_RS485_FRAME) {
        fap_codec_frame f = {
            .offset = sc->rep_start, .data = sc->f.data, .data_len = sc->f.count,
            .field = {sc->f.address, (sc->f.datalen & MIKROC_RS485_DL_MASTER) != 0},
        };
        lf_codec_span_frame(&s->span, &f, sc->rep_end, k);
    } else {
        lf_codec_span_reject(&s->span, sc->rep_start, sc->rep_end, mikroc_code(sc->reason), k);
    }
    sc->code = 0;
}

/* Bytes before this offset start no frame (a start byte opens one at once). */
static uint64_t mikroc_held_from(const mikroc_state *s)
{
    return lf_mikroc_scan_in_frame(&s->sc) ? s->sc.start : s->sc.pos;
}

static void mikroc_feed(void *state, const uint8_t *p, size_t n, int64_t now_ns,
                        fap_codec_frame_cb on_frame, fap_codec_reject_cb on_reject, void *ctx)
{
    (void)now_ns;
    mikroc_state *s = state;
    const lf_codec_sink k = {on_frame, on_reject, ctx};
    while (n > 0) {
        size_t used = lf_mikroc_scan_feed(&s->sc, p, n);
        uint64_t keep = mikroc_held_from(s);
        if (s->sc.code != 0 && s->sc.rep_start < keep)
            keep = s->sc.rep_start;           /* the report below still needs its bytes */
        lf_codec_span_push(&s->span, p, used, keep, &k);
        p += used;
        n -= used;
        if (s->sc.code != 0)
            mikroc_report(s, &k);
    }
    lf_codec_span_garbage(&s->span, mikroc_held_from(s), &k);
}

LF_CODEC_TICK_BY_FEED(mikroc)

static void mikroc_finish(void *state, fap_codec_frame_cb on_frame,
                          fap_codec_reject_cb on_reject, void *ctx)
{
    mikroc_state *s = state;
    const lf_codec_sink k = {on_frame, on_reject, ctx};
    lf_codec_span_end(&s->span, lf_mikroc_scan_in_frame(&s->sc), s->sc.start, s->sc.pos, &k);
    mikrocRS485_DecoderInit(&s->sc.d);
}

static const char *mikroc_reject_name(int code)
{
    const char *r = lf_codec_shared_name(code);
    if (!r && code >= 2 && (size_t)(code - 2) < N_REASONS)
        r = mikroc_reasons[code - 2];
    return r ? r : "?";
}

static size_t mikroc_missing(const void *state)
{
    return lf_mikroc_missing(&((const mikroc_state *)state)->sc.d);
}

static size_t mikroc_encode(uint8_t *out, size_t cap, const unsigned *field,
                            const uint8_t *data, size_t len)
{
    if (field[0] > 0xFF || field[1] > 1 || len > MIKROC_RS485_MAX_DATA ||
        cap < MIKROC_RS485_FRAME_MAX)
        return 0;
    int n = mikrocRS485_Encode(out, data, (unsigned)len, (uint8_t)field[0], (int)field[1]);
    return n > 0 ? (size_t)n : 0;
}

static const fap_codec row =
    LF_CODEC_ROW(mikroc, lf_codec_never, lf_codec_unnamed, MIKROC_RS485_FRAME_MAX);
LF_CODEC_ENTRY(mikroc, row, NULL);
