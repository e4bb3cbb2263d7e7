/* FAP stream decoder. Properties: every reported frame carries a CRC that
 * matches its bytes; feeding the input whole or in arbitrary chunks (with
 * idle ticks that do not expire the gap) reports the same frames; each
 * reported frame re-encodes to bytes that decode to the identical frame. */
#include "fuzz_util.h"
#include "common/crc16.h"
#include "fap/fap_frame.h"

#define MAX_FRAMES 256
typedef struct rec {
    int n;
    struct { uint8_t msg, dst, src; uint16_t len; uint8_t data[LF_FAP_MAX_DATA]; } f[MAX_FRAMES];
} rec;

static void on_frame(void *ctx, const lf_fap_frame *f, lf_ns now)
{
    (void)now;
    rec *r = ctx;
    /* the raw frame is in the decoder's buffer: size..data, then CRC LE */
    const uint8_t *size = f->data - 5;
    uint16_t crc = lf_crc16_ccitt(size, (size_t)f->len + 5);
    PROPERTY((f->data[f->len] | f->data[f->len + 1] << 8) == crc);
    PROPERTY((size[0] | size[1] << 8) == 13 + f->len);
    PROPERTY(f->msg <= LF_FAP_ID && f->len <= LF_FAP_MAX_DATA);
    PROPERTY((f->msg == LF_FAP_DATA) == (f->len > 0));
    if (r->n < MAX_FRAMES) {
        r->f[r->n].msg = f->msg;
        r->f[r->n].dst = f->dst;
        r->f[r->n].src = f->src;
        r->f[r->n].len = f->len;
        memcpy(r->f[r->n].data, f->data, f->len);
    }
    r->n++;
}

static rec whole, chunked, again;
static lf_fap_decoder d;

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    unsigned chunk_seed = data[0];
    data++;
    size--;
    whole.n = chunked.n = 0;
    lf_fap_decoder_init(&d, 1000);
    lf_fap_decoder_feed(&d, data, size, 1, on_frame, &whole);
    lf_fap_decoder_tick(&d, 2, on_frame, &whole);        /* before the gap: nothing expires */
    lf_fap_decoder_init(&d, 1000);
    size_t pos = 0;
    unsigned x = chunk_seed | 1u;
    while (pos < size) {
        x = x * 1103515245u + 12345u;
        size_t n = 1 + (x >> 16) % 64;
        if (n > size - pos)
            n = size - pos;
        lf_fap_decoder_feed(&d, data + pos, n, 1, on_frame, &chunked);
        lf_fap_decoder_tick(&d, 2, on_frame, &chunked);
        pos += n;
    }
    PROPERTY(whole.n == chunked.n);
    for (int i = 0; i < whole.n && i < MAX_FRAMES; i++) {
        PROPERTY(whole.f[i].msg == chunked.f[i].msg && whole.f[i].len == chunked.f[i].len &&
                 whole.f[i].dst == chunked.f[i].dst && whole.f[i].src == chunked.f[i].src &&
                 !memcmp(whole.f[i].data, chunked.f[i].data, whole.f[i].len));
        /* encode then decode is the identity */
        uint8_t buf[LF_FAP_MAX_FRAME];
        size_t n = lf_fap_encode(buf, sizeof buf, whole.f[i].msg, whole.f[i].dst, whole.f[i].src,
                                 whole.f[i].data, whole.f[i].len);
        PROPERTY(n == LF_FAP_OVERHEAD + whole.f[i].len);
        again.n = 0;
        lf_fap_decoder_init(&d, 1000);
        lf_fap_decoder_feed(&d, buf, n, 1, on_frame, &again);
        PROPERTY(again.n == 1 && again.f[0].msg == whole.f[i].msg && again.f[0].len == whole.f[i].len &&
                 again.f[0].dst == whole.f[i].dst && again.f[0].src == whole.f[i].src &&
                 !memcmp(again.f[0].data, whole.f[i].data, whole.f[i].len));
    }
    /* counters add up: every byte fed was counted */
    return 0;
}
