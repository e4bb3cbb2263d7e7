/* FAP stream decoder, through its row of the codec table (fap_codec.h).
 * Properties: every reported frame carries a CRC that matches its bytes;
 * feeding the input whole or in arbitrary chunks (with idle ticks that do
 * not expire the gap) reports the same frames and rejects; each reported
 * frame re-encodes to bytes that decode to the identical frame; plus the
 * properties every row keeps (fuzz_codec.h). */
#include "fuzz_codec.h"
#include "common/crc16.h"
#include "fap/codec.h"

static fzc_log whole, chunked, again;

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    unsigned chunk_seed = data[0];
    data++;
    size--;
    const fap_codec *c = fap_codec_find("fap");
    PROPERTY(c != NULL && c->n_fields == 3);
    fzc_decode(c, data, size, 0, 0, &whole);
    fzc_decode(c, data, size, chunk_seed, 0, &chunked);
    fzc_same(&whole, &chunked);
    for (int i = 0; i < whole.n && i < FZC_MAX; i++) {
        const fzc_ev *e = &whole.ev[i];
        if (e->code != 0)
            continue;
        /* the raw frame: marker, size..data, then CRC LE over size..data */
        const uint8_t *raw = data + e->offset;
        size_t len = e->len;
        PROPERTY(len == LF_FAP_OVERHEAD + e->data_len);
        uint16_t crc = lf_crc16_ccitt(raw + LF_FAP_MARKER_LEN, len - LF_FAP_MARKER_LEN - 2);
        PROPERTY((uint16_t)(raw[len - 2] | raw[len - 1] << 8) == crc);
        PROPERTY((size_t)(raw[8] | raw[9] << 8) == 13 + e->data_len);
        unsigned msg = e->field[0];
        PROPERTY(msg <= LF_FAP_ID && e->data_len <= LF_FAP_MAX_DATA);
        PROPERTY((msg == LF_FAP_DATA) == (e->data_len > 0));
        fap_codec_frame named = {.field = {msg}};
        PROPERTY(c->frame_name(&named) != NULL);
        /* encode then decode is the identity */
        uint8_t buf[LF_FAP_MAX_FRAME];
        size_t n = lf_fap_encode(buf, sizeof buf, msg, e->field[1], e->field[2], e->data, e->data_len);
        PROPERTY(n == len);
        fzc_decode(c, buf, n, 0, 1, &again);
        PROPERTY(again.n == 1 && again.ev[0].code == 0 && again.ev[0].len == n &&
                 !memcmp(again.ev[0].field, e->field, sizeof e->field) &&
                 again.ev[0].data_len == e->data_len &&
                 !memcmp(again.ev[0].data, e->data, e->data_len));
    }
    return 0;
}
