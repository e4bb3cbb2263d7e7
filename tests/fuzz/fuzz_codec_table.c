/* Every row of the codec table (fap_codec.h), found through fap_codec_at():
 * a row added to the table is fuzzed here with no edit. The input starts
 * with the row's name and a NUL (the seeds' form; an unknown or missing
 * name picks row input[0] % rows), then a chunk seed byte, then the bytes.
 * Properties, for every row: the same frames and rejects whole and in
 * chunks, in stream order, inside the input, each frame's raw bytes the
 * input's at its offset (fuzz_codec.h); every reject code named; and each
 * good frame re-encoded from its fields and data (encode) decodes to one
 * frame with the same fields and data. */
#include "fuzz_codec.h"

static fzc_log whole, chunked, again;

static const fap_codec *pick(const uint8_t **data, size_t *size)
{
    size_t n = 0;
    while (fap_codec_at(n))
        n++;
    const uint8_t *nul = memchr(*data, 0, *size < 16 ? *size : 16);
    if (nul) {
        char name[16];
        size_t len = (size_t)(nul - *data);
        memcpy(name, *data, len);
        name[len] = 0;
        const fap_codec *c = fap_codec_find(name);
        *size -= len + 1;
        *data += len + 1;
        if (c)
            return c;
    }
    return fap_codec_at(*size ? (*data)[0] % n : 0);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const fap_codec *c = pick(&data, &size);
    PROPERTY(c != NULL && c->n_fields >= 1 && c->n_fields <= FAP_CODEC_MAX_FIELDS);
    if (size < 1)
        return 0;
    unsigned chunk_seed = data[0];
    data++;
    size--;
    fzc_decode(c, data, size, 0, 0, &whole);
    fzc_decode(c, data, size, chunk_seed, 0, &chunked);
    fzc_same(&whole, &chunked);
    static uint8_t buf[1 << 13];
    PROPERTY(c->max_frame <= sizeof buf);
    for (int i = 0; i < whole.n && i < FZC_MAX; i++) {
        const fzc_ev *e = &whole.ev[i];
        if (e->code != 0)
            continue;
        size_t n = c->encode(buf, c->max_frame, e->field, e->data, e->data_len);
        PROPERTY(n > 0 && n <= c->max_frame);
        fzc_decode(c, buf, n, 0, 0, &again);
        PROPERTY(again.n == 1 && again.ev[0].code == 0 && again.ev[0].len == n &&
                 !memcmp(again.ev[0].field, e->field, sizeof e->field) &&
                 again.ev[0].data_len == e->data_len &&
                 !memcmp(again.ev[0].data, e->data, e->data_len));
    }
    return 0;
}
