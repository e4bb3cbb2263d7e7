/* mikroC RS-485: its row of the codec table (fap_codec.h) over the input,
 * whole and chunked (fuzz_codec.h: same reports, tiling the stream), one
 * table report per report of the decoder; the decoder and the master and slave receive paths
 * (mikrocRS485_CtxReceiveByte, the vendor's byte-at-a-time interrupt
 * routine), on arbitrary bytes. Properties: a decoded frame re-encodes to
 * bytes that decode to the identical frame; encode then decode of the
 * input's own (data, address, direction) is the identity; the receive
 * buffers only ever get the flags 0 or 255 and a count 0..3; a slave
 * never stores a frame from a slave or for another (non-broadcast)
 * address. */
#include "fuzz_codec.h"
#include "mikroc_rs485.h"

static fzc_log whole, chunked;

static void decode_all(const uint8_t *p, size_t n, mikrocRS485_frame *last, int *frames)
{
    mikrocRS485_decoder d;
    mikrocRS485_DecoderInit(&d);
    *frames = 0;
    for (size_t i = 0; i < n; i++) {
        mikrocRS485_frame fr;
        int r = mikrocRS485_DecoderFeed(&d, p[i], &fr);
        PROPERTY(r == MIKROC_RS485_MORE || r == MIKROC_RS485_FRAME ||
                 (r <= MIKROC_RS485_ECRC && r >= MIKROC_RS485_EOVERRUN));
        if (r == MIKROC_RS485_FRAME) {
            *last = fr;
            (*frames)++;
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 2)
        return 0;
    const fap_codec *c = fap_codec_find("mikroc");
    PROPERTY(c != NULL && c->n_fields == 2);
    fzc_decode(c, data + 1, size - 1, 0, 1, &whole);
    fzc_decode(c, data + 1, size - 1, data[0], 1, &chunked);
    fzc_same(&whole, &chunked);
    int k = 0;                         /* reports of the decoder below, in order */
    uint8_t slave_addr = data[0];
    mikrocRS485_ctx master, slave;
    mikrocRS485_CtxInitMaster(&master);
    mikrocRS485_CtxInitSlave(&slave, slave_addr);
    char mbuf[MIKROC_RS485_MASTER_BUFFER] = {0}, sbuf[MIKROC_RS485_SLAVE_BUFFER] = {0};
    mikrocRS485_decoder d;
    mikrocRS485_DecoderInit(&d);
    for (size_t i = 1; i < size; i++) {
        mikrocRS485_CtxReceiveByte(&master, mbuf, data[i]);
        mikrocRS485_CtxReceiveByte(&slave, sbuf, data[i]);
        for (int k = MIKROC_RS485_IDX_READY; k <= MIKROC_RS485_IDX_ERROR; k++) {
            PROPERTY((uint8_t)mbuf[k] == 0 || (uint8_t)mbuf[k] == 255);
            PROPERTY((uint8_t)sbuf[k] == 0 || (uint8_t)sbuf[k] == 255);
        }
        PROPERTY((uint8_t)mbuf[MIKROC_RS485_IDX_COUNT] <= 3 && (uint8_t)sbuf[MIKROC_RS485_IDX_COUNT] <= 3);
        /* the application takes a frame now and then (clears the flags) */
        if (data[i] & 1) {
            mbuf[MIKROC_RS485_IDX_READY] = mbuf[MIKROC_RS485_IDX_ERROR] = 0;
            sbuf[MIKROC_RS485_IDX_READY] = sbuf[MIKROC_RS485_IDX_ERROR] = 0;
        }
        mikrocRS485_frame fr;
        int r = mikrocRS485_DecoderFeed(&d, data[i], &fr);
        if (r != MIKROC_RS485_MORE) {
            PROPERTY(k < whole.n);
            if (k < FZC_MAX)
                PROPERTY((r == MIKROC_RS485_FRAME) == (whole.ev[k].code == 0));
            if (k < FZC_MAX && r == MIKROC_RS485_FRAME)
                PROPERTY(whole.ev[k].field[0] == fr.address &&
                         whole.ev[k].field[1] == !!(fr.datalen & MIKROC_RS485_DL_MASTER) &&
                         whole.ev[k].data_len == fr.count && !memcmp(whole.ev[k].data, fr.data, fr.count));
            k++;
        }
        if (r == MIKROC_RS485_FRAME) {
            PROPERTY(fr.count <= 3 && !(fr.datalen & MIKROC_RS485_DL_FIXED));
            uint8_t out[MIKROC_RS485_FRAME_MAX];
            int from_master = !!(fr.datalen & MIKROC_RS485_DL_MASTER);
            int n = mikrocRS485_Encode(out, fr.data, fr.count, fr.address, from_master);
            PROPERTY(n == MIKROC_RS485_FRAME_MIN + fr.count);
            mikrocRS485_frame back = {0};
            int frames;
            decode_all(out, (size_t)n, &back, &frames);
            PROPERTY(frames == 1 && back.address == fr.address && back.count == fr.count &&
                     back.datalen == fr.datalen && !memcmp(back.data, fr.data, fr.count));
        }
    }
    PROPERTY(whole.n == k || (whole.n == k + 1 && (k >= FZC_MAX ||
                                                    whole.ev[k].code == FAP_CODEC_TRUNCATED)));
    mikrocRS485_stats ms, ss;
    mikrocRS485_CtxGetStats(&master, &ms);
    mikrocRS485_CtxGetStats(&slave, &ss);
    PROPERTY(ms.overruns <= ms.errors && ss.overruns <= ss.errors);
    /* encode then decode: the input's own fields */
    uint8_t payload[3] = {data[1], size > 2 ? data[2] : 0, size > 3 ? data[3] : 0};
    unsigned count = data[0] % 4;
    uint8_t out[MIKROC_RS485_FRAME_MAX];
    int n = mikrocRS485_Encode(out, payload, count, data[1], data[0] & 0x80);
    PROPERTY(n == (int)(MIKROC_RS485_FRAME_MIN + count));
    mikrocRS485_frame back = {0};
    int frames;
    decode_all(out, (size_t)n, &back, &frames);
    PROPERTY(frames == 1 && back.address == data[1] && back.count == count &&
             !memcmp(back.data, payload, count) &&
             !!(back.datalen & MIKROC_RS485_DL_MASTER) == !!(data[0] & 0x80));
    return 0;
}
