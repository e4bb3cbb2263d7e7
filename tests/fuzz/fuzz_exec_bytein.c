/* exec async's row of the codec table (fap_codec.h) over the input, whole
 * and chunked (fuzz_codec.h: same reports, tiling the stream), its good
 * frames exactly the ones execAsyncByteIn reports byte by byte; then
 * execAsyncByteIn from a zero-filled state (as an interrupt routine's
 * static state), fed on after every true return, with a Buffer of exactly
 * BufferSize bytes on the heap (ASan sees any write past it).
 * Properties: a true return carries a known Status; Length never exceeds
 * the buffer; a GOOD frame re-encoded with execAsyncBufferOut decodes to
 * the identical frame (encode then decode is the identity), and the frame
 * the fuzzer built itself (second half of the input) always decodes GOOD. */
#include "fuzz_codec.h"
#include "exec_async.h"

static fzc_log whole, chunked;

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const fap_codec *c = fap_codec_find("exec");
    PROPERTY(c != NULL && c->n_fields == 2);
    fzc_decode(c, data, size, 0, 1, &whole);
    fzc_decode(c, data, size, size ? data[0] : 1, 1, &chunked);
    fzc_same(&whole, &chunked);
    {   /* one table report per report of the receiver (and a truncated tail) */
        struct execAsyncStateDef s0;
        static byte b0[EXEC_ASYNC_MAX_DATA];
        memset(&s0, 0, sizeof s0);
        int k = 0;
        for (size_t i = 0; i < size; i++) {
            if (!execAsyncByteIn(data[i], &s0, b0))
                continue;
            PROPERTY(k < whole.n);
            if (k < FZC_MAX) {
                const fzc_ev *e = &whole.ev[k];
                if (s0.Status == EXEC_ASYNC_GOOD)
                    PROPERTY(e->code == 0 && e->field[0] == s0.Node && e->field[1] == s0.SeqNo &&
                             e->data_len == s0.Length && !memcmp(e->data, b0, s0.Length));
                else
                    PROPERTY(e->code == s0.Status);
            }
            k++;
        }
        PROPERTY(whole.n == k || (whole.n == k + 1 && (k >= FZC_MAX ||
                                                        whole.ev[k].code == FAP_CODEC_TRUNCATED)));
    }
    fz f = {data, size};
    byte bufsize = fz_u8(&f);                 /* 0 = 255 */
    size_t cap = bufsize ? bufsize : 255;
    byte *buf = malloc(cap);
    struct execAsyncStateDef st;
    memset(&st, 0, sizeof st);
    st.BufferSize = bufsize;
    byte tx[EXEC_ASYNC_MAX_FRAME];
    static byte again[255];
    while (fz_more(&f)) {
        if (!execAsyncByteIn(fz_u8(&f), &st, buf))
            continue;
        PROPERTY(st.Status >= EXEC_ASYNC_GOOD && st.Status <= EXEC_ASYNC_FRAMING);
        if (st.Status != EXEC_ASYNC_GOOD)
            continue;
        PROPERTY(st.Length <= cap);
        word n = execAsyncBufferOut(st.Node, buf, tx, (byte)st.Length, st.SeqNo);
        PROPERTY(n <= EXEC_ASYNC_FRAME_SIZE(st.Length));
        struct execAsyncStateDef s2;
        memset(&s2, 0, sizeof s2);
        int done = 0;
        for (word i = 0; i < n; i++) {
            boolean r = execAsyncByteIn(tx[i], &s2, again);
            PROPERTY(!r || i == n - 1);       /* exactly one frame, at its end */
            done = r;
        }
        PROPERTY(done && s2.Status == EXEC_ASYNC_GOOD && s2.Node == st.Node &&
                 s2.SeqNo == st.SeqNo && s2.Length == st.Length &&
                 !memcmp(again, buf, st.Length));
    }
    free(buf);
    /* a frame of the input's own bytes: always GOOD, whatever they are */
    byte node = size > 1 ? data[1] : 0, seq = size > 2 ? data[2] : 0;
    byte raw[255];
    size_t len = size > 255 ? 255 : size;
    memcpy(raw, data, len);
    word n = execAsyncBufferOut(node, raw, tx, (byte)len, seq);
    PROPERTY(n >= len + 8 && n <= EXEC_ASYNC_FRAME_SIZE(len));
    memset(&st, 0, sizeof st);
    int got = 0;
    for (word i = 0; i < n; i++)
        got += execAsyncByteIn(tx[i], &st, again);
    PROPERTY(got == 1 && st.Status == EXEC_ASYNC_GOOD && st.Length == len &&
             st.Node == node && st.SeqNo == seq && !memcmp(again, raw, len));
    return 0;
}
