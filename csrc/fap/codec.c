/* FAP frame encoder and streaming decoder. See fap/codec.h.
 *
 * The decoder keeps at most one candidate frame in its buffer, always
 * starting at buf[0]. A rejected candidate (bad size, msg, CRC or a stale
 * partial) loses only its FIRST byte: the search resumes at the next byte,
 * never after the claimed size, so a damaged frame cannot swallow a good
 * frame that follows it. */
#include "fap/codec.h"
#include "common/crc16.h"
#include "fap_trace.h"
#include <string.h>

size_t lf_fap_encode(uint8_t *out, size_t cap, unsigned msg, unsigned dst,
                     unsigned src, const uint8_t *data, size_t len)
{
    if (msg > LF_FAP_ID || dst > 0xFF || src > 0xFF)
        return 0;
    if (msg == LF_FAP_DATA ? (len == 0 || len > LF_FAP_MAX_DATA) : len != 0)
        return 0;
    size_t size = LF_FAP_HDR_LEN + len;
    if (cap < size + LF_FAP_CRC_LEN)
        return 0;
    memcpy(out, LF_FAP_MARKER, LF_FAP_MARKER_LEN);
    out[8] = (uint8_t)(size & 0xFF);
    out[9] = (uint8_t)(size >> 8);
    out[LF_FAP_MSG_AT] = (uint8_t)msg;
    out[11] = (uint8_t)dst;
    out[12] = (uint8_t)src;
    if (len)
        memcpy(out + LF_FAP_HDR_LEN, data, len);
    uint16_t crc = lf_crc16_ccitt(out + LF_FAP_MARKER_LEN, size - LF_FAP_MARKER_LEN);
    out[size] = (uint8_t)(crc & 0xFF);
    out[size + 1] = (uint8_t)(crc >> 8);
    return size + LF_FAP_CRC_LEN;
}

lf_ns lf_fap_default_gap(unsigned baud)
{
    lf_ns four = 4 * lf_char_time_ns(baud);
    lf_ns ten = 10 * LF_NS_PER_MS;
    return four > ten ? four : ten;
}

void lf_fap_decoder_init(lf_fap_decoder *d, lf_ns gap)
{
    memset(d, 0, sizeof *d);
    d->gap = gap > 0 ? gap : lf_fap_default_gap(0);
}

void lf_fap_decoder_reset(lf_fap_decoder *d)
{
    d->pos += d->n;
    d->n = 0;
}

void lf_fap_decoder_on_reject(lf_fap_decoder *d, lf_fap_reject_cb cb, void *ctx)
{
    d->reject = cb;
    d->reject_ctx = ctx;
}

const char *lf_fap_reject_name(int reason)
{
    switch (reason) {
    case LF_FAP_REJ_GARBAGE:  return "garbage";
    case LF_FAP_REJ_SIZE:     return "size";
    case LF_FAP_REJ_MSG:      return "msg";
    case LF_FAP_REJ_MSG_SIZE: return "msg/size";
    case LF_FAP_REJ_CRC:      return "crc";
    case LF_FAP_REJ_GAP:      return "gap";
    default:                  return "?";
    }
}

/* Tell the reject callback about the first n held bytes. */
static void tell(lf_fap_decoder *d, int reason, size_t n, lf_ns now)
{
    if (d->reject && n)
        d->reject(d->reject_ctx, reason, d->buf, n, d->pos, now);
}

/* Drop k bytes from the front of the buffer. */
static void drop(lf_fap_decoder *d, size_t k)
{
    if (k >= d->n) {
        d->pos += d->n;
        d->n = 0;
        return;
    }
    d->pos += k;
    memmove(d->buf, d->buf + k, d->n - k);
    d->n -= k;
}

/* Reject the candidate at buf[0] (its first n bytes were examined):
 * resume the search one byte later. */
static void reject(lf_fap_decoder *d, uint64_t *counter, int reason, size_t n, lf_ns now)
{
    (*counter)++;
    tell(d, reason, n, now);
    drop(d, 1);
}

/* How many leading bytes match the marker (either spelling). */
static int marker_prefix_ok(const uint8_t *b, size_t n)
{
    size_t m = n < LF_FAP_MARKER_LEN ? n : LF_FAP_MARKER_LEN;
    for (size_t i = 0; i < m; i++) {
        if (b[i] == (uint8_t)LF_FAP_MARKER[i])
            continue;
        if (i == 7 && b[i] == 'f')
            continue;
        return 0;
    }
    return 1;
}

/* Parse the buffer: report complete frames, reject bad candidates, stop
 * when the buffer holds only a (so far) valid prefix. */
static void parse(lf_fap_decoder *d, lf_ns now, lf_fap_frame_cb cb, void *ctx)
{
    while (d->n > 0) {
        if (d->buf[0] != 'c') {
            uint8_t *c = memchr(d->buf, 'c', d->n);
            size_t skip = c ? (size_t)(c - d->buf) : d->n;
            d->c.garbage_bytes += skip;
            tell(d, LF_FAP_REJ_GARBAGE, skip, now);
            drop(d, skip);
            continue;
        }
        if (!marker_prefix_ok(d->buf, d->n)) {
            reject(d, &d->c.garbage_bytes, LF_FAP_REJ_GARBAGE, 1, now);
            continue;
        }
        if (d->n < 10)
            return;
        unsigned size = (unsigned)d->buf[8] | ((unsigned)d->buf[9] << 8);
        if (size < LF_FAP_HDR_LEN || size > LF_FAP_HDR_LEN + LF_FAP_MAX_DATA) {
            reject(d, &d->c.framing_errors, LF_FAP_REJ_SIZE, 10, now);
            continue;
        }
        if (d->n <= LF_FAP_MSG_AT)
            return;
        unsigned msg = d->buf[LF_FAP_MSG_AT];
        if (msg > LF_FAP_ID || (msg == LF_FAP_DATA) != (size > LF_FAP_HDR_LEN)) {
            reject(d, &d->c.framing_errors,
                   msg > LF_FAP_ID ? LF_FAP_REJ_MSG : LF_FAP_REJ_MSG_SIZE, 11, now);
            continue;
        }
        size_t total = size + LF_FAP_CRC_LEN;
        if (d->n < total)
            return;
        uint16_t want = (uint16_t)(d->buf[size] | (d->buf[size + 1] << 8));
        if (lf_crc16_ccitt(d->buf + LF_FAP_MARKER_LEN, size - LF_FAP_MARKER_LEN) != want) {
            reject(d, &d->c.crc_errors, LF_FAP_REJ_CRC, total, now);
            continue;
        }
        lf_fap_frame f = {
            .msg = (uint8_t)msg, .dst = d->buf[11], .src = d->buf[12],
            .len = (uint16_t)(size - LF_FAP_HDR_LEN), .data = d->buf + LF_FAP_HDR_LEN,
            .raw = d->buf, .raw_len = total, .offset = d->pos,
        };
        d->c.frames++;
        if (cb)
            cb(ctx, &f, now);
        drop(d, total);
    }
}

lf_ns lf_fap_decoder_deadline(const lf_fap_decoder *d)
{
    return d->n ? d->last_byte + d->gap : LF_NEVER;
}

size_t lf_fap_decoder_missing(const lf_fap_decoder *d)
{
    if (d->n == 0)
        return 0;
    if (d->n < 10)                    /* size not in yet: a frame without data */
        return LF_FAP_OVERHEAD - d->n;
    /* parse() keeps only a valid prefix: the size field is in range */
    size_t total = ((size_t)d->buf[8] | ((size_t)d->buf[9] << 8)) + LF_FAP_CRC_LEN;
    return total > d->n ? total - d->n : 0;
}

int lf_fap_decoder_msg(const lf_fap_decoder *d)
{
    return d->n > LF_FAP_MSG_AT ? d->buf[LF_FAP_MSG_AT] : -1;
}

void lf_fap_decoder_tick(lf_fap_decoder *d, lf_ns now, lf_fap_frame_cb cb, void *ctx)
{
    if (d->n == 0 || now < d->last_byte + d->gap)
        return;
    d->c.gap_timeouts++;
    tell(d, LF_FAP_REJ_GAP, d->n, now);
    /* Everything held is equally stale: keep rejecting first bytes until
     * the rescan either empties the buffer or reports what it finds. */
    while (d->n > 0) {
        d->c.garbage_bytes++;
        drop(d, 1);
        parse(d, now, cb, ctx);
    }
}

void lf_fap_decoder_feed(lf_fap_decoder *d, const uint8_t *p, size_t n, lf_ns now,
                         lf_fap_frame_cb cb, void *ctx)
{
    d->c.bytes += n;
    while (n > 0) {
        size_t room = sizeof d->buf - d->n;
        size_t k = n < room ? n : room;
        memcpy(d->buf + d->n, p, k);
        d->n += k;
        p += k;
        n -= k;
        d->last_byte = now;
        parse(d, now, cb, ctx);
    }
}
