/* mikroC RS-485 frame codec: encoder and byte-wise decoder. Pure functions
 * on bytes, no I/O (docs/protocols.md, docs/mikroc.md). */
#include <errno.h>
#include <string.h>

#include "mikroc_rs485.h"
#include "mikroc/codec.h"
#include "mikroc/mikroc_internal.h"

#define START MIKROC_RS485_START_BYTE
#define STOP MIKROC_RS485_STOP_BYTE

static int is_marker(uint8_t b)
{
    return b == START || b == STOP;
}

/* ~(XOR of the bytes as sent); never equal to a marker byte. */
static uint8_t frame_crc(const uint8_t *fields, unsigned n)
{
    uint8_t x = 0;
    for (unsigned i = 0; i < n; i++)
        x ^= fields[i];
    x = (uint8_t)~x;
    if (is_marker(x))
        x++;
    return x;
}

int mikrocRS485_Encode(uint8_t *out, const uint8_t *data, unsigned datalen,
                       uint8_t address, int from_master)
{
    if (!out || datalen > MIKROC_RS485_MAX_DATA || (datalen && !data))
        return -EINVAL;
    uint8_t dl = (uint8_t)datalen;
    if (from_master)
        dl |= MIKROC_RS485_DL_MASTER;
    uint8_t addr = address;
    if (is_marker(addr)) {
        addr ^= 1;
        dl |= MIKROC_RS485_DL_ADDR_ESC;
    }
    unsigned n = 0;
    out[n++] = START;
    out[n++] = addr;
    out[n++] = 0;          /* DATALEN, once the data flags are known */
    for (unsigned i = 0; i < datalen; i++) {
        uint8_t b = data[i];
        if (is_marker(b)) {
            b ^= 1;
            dl |= (uint8_t)MIKROC_RS485_DL_DATA_ESC(i);
        }
        out[n++] = b;
    }
    out[2] = dl;
    out[n] = frame_crc(out + 1, n - 1);
    n++;
    out[n++] = STOP;
    return (int)n;
}

void mikrocRS485_DecoderInit(mikrocRS485_decoder *d)
{
    memset(d, 0, sizeof *d);
}

/* Describe the part of the frame that arrived (for error reports). */
static void describe_partial(const mikrocRS485_decoder *d, mikrocRS485_frame *out)
{
    memset(out, 0, sizeof *out);
    if (d->n >= 1) {
        out->header = 1;
        out->address = d->raw[0];
    }
    if (d->n >= 2) {
        out->header = 2;
        out->datalen = d->raw[1];
        out->count = d->raw[1] & MIKROC_RS485_DL_COUNT;
        if ((out->datalen & MIKROC_RS485_DL_ADDR_ESC) && is_marker(d->raw[0] ^ 1))
            out->address = d->raw[0] ^ 1;
    }
}

/* End the current frame with an error and skip bytes until the next start. */
static int fail(mikrocRS485_decoder *d, mikrocRS485_frame *out, int code)
{
    describe_partial(d, out);
    d->in_frame = 0;
    d->n = 0;
    return code;
}

/* A flagged field must have been a marker byte; an unflagged one cannot be. */
static int unescape(uint8_t raw, int flagged, uint8_t *value)
{
    if (!flagged) {
        *value = raw;
        return 0;
    }
    if (!is_marker(raw ^ 1))
        return -1;
    *value = raw ^ 1;
    return 0;
}

/* The stop byte arrived where expected: check the whole frame. */
static int finish(mikrocRS485_decoder *d, mikrocRS485_frame *out)
{
    const uint8_t dl = d->raw[1];
    const unsigned count = dl & MIKROC_RS485_DL_COUNT;
    const unsigned crc_at = 2 + count;

    if (d->raw[crc_at] != frame_crc(d->raw, crc_at))
        return fail(d, out, MIKROC_RS485_ECRC);
    mikrocRS485_frame f;
    memset(&f, 0, sizeof f);
    f.header = 2;
    f.datalen = dl;
    f.count = (uint8_t)count;
    int bad = unescape(d->raw[0], dl & MIKROC_RS485_DL_ADDR_ESC, &f.address);
    for (unsigned i = 0; i < count; i++)
        bad |= unescape(d->raw[2 + i], dl & MIKROC_RS485_DL_DATA_ESC(i), &f.data[i]);
    if (bad)
        return fail(d, out, MIKROC_RS485_EFORMAT);
    *out = f;
    d->in_frame = 0;
    d->n = 0;
    return MIKROC_RS485_FRAME;
}

int mikrocRS485_DecoderFeed(mikrocRS485_decoder *d, uint8_t byte, mikrocRS485_frame *out)
{
    if (byte == START) {
        /* 0x96 never occurs inside a frame: it always starts a new one. */
        int r = MIKROC_RS485_MORE;
        if (d->in_frame)
            r = fail(d, out, MIKROC_RS485_EABORT);
        d->in_frame = 1;
        d->n = 0;
        return r;
    }
    if (!d->in_frame)
        return MIKROC_RS485_MORE;     /* noise between frames */

    const unsigned pos = d->n;        /* index of this byte in raw[] */
    if (pos >= 2) {
        const uint8_t dl = d->raw[1];
        const unsigned stop_at = 2 + (dl & MIKROC_RS485_DL_COUNT) + 1;
        if (pos == stop_at) {
            if (byte != STOP)
                return fail(d, out, MIKROC_RS485_ELONG);
            return finish(d, out);
        }
    }
    if (byte == STOP)
        return fail(d, out, MIKROC_RS485_ESHORT);
    d->raw[d->n++] = byte;
    if (pos == 1) {
        const unsigned count = byte & MIKROC_RS485_DL_COUNT;
        const unsigned flags = (byte >> 2) & 7u;
        /* bit 5 is fixed 0; a data flag needs its data byte */
        if ((byte & MIKROC_RS485_DL_FIXED) || (flags >> count) != 0)
            return fail(d, out, MIKROC_RS485_EFORMAT);
    }
    return MIKROC_RS485_MORE;
}

void lf_mikroc_scan_init(lf_mikroc_scan *s)
{
    memset(s, 0, sizeof *s);
    mikrocRS485_DecoderInit(&s->d);
}

/* The short reason of an error code; which field broke an EFORMAT is
 * told by the byte's place in the frame (DATALEN is checked on arrival,
 * the escape flags at the stop byte). */
static const char *scan_reason(int code, uint64_t index)
{
    switch (code) {
    case MIKROC_RS485_ECRC:    return "crc";
    case MIKROC_RS485_EFORMAT: return index == 2 ? "datalen" : "escape";
    case MIKROC_RS485_ESHORT:  return "short";
    case MIKROC_RS485_ELONG:   return "long";
    case MIKROC_RS485_EABORT:  return "abort";
    default:                   return NULL;
    }
}

size_t lf_mikroc_scan_feed(lf_mikroc_scan *s, const uint8_t *p, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        uint64_t at = s->pos++;
        int r = mikrocRS485_DecoderFeed(&s->d, p[i], &s->f);
        if (p[i] == START) {
            uint64_t prev = s->start;
            s->start = at;
            if (r == MIKROC_RS485_MORE)
                continue;
            s->rep_start = prev;
            s->rep_end = at;
        } else {
            if (r == MIKROC_RS485_MORE)
                continue;
            s->rep_start = s->start;
            s->rep_end = at + 1;
        }
        s->code = r;
        s->reason = scan_reason(r, at - s->rep_start);
        return i + 1;
    }
    return n;
}

int lf_mikroc_scan_in_frame(const lf_mikroc_scan *s)
{
    return s->d.in_frame != 0;
}

size_t lf_mikroc_missing(const mikrocRS485_decoder *d)
{
    /* after START: address, DATALEN, data (DATALEN's count), CRC, STOP */
    if (!d->in_frame)
        return 5;
    unsigned count = d->n >= 2 ? (d->raw[1] & MIKROC_RS485_DL_COUNT) : 0;
    return count + 4u > d->n ? count + 4u - d->n : 1;
}

size_t lf_mikroc_expect(const mikrocRS485_decoder *d)
{
    size_t missing = lf_mikroc_missing(d);
    if (d->in_frame && d->n >= 2)
        return missing;              /* DATALEN is in: exact */
    size_t held = d->in_frame ? 1u + d->n : 0;
    size_t rest = MIKROC_RS485_FRAME_MAX > held ? MIKROC_RS485_FRAME_MAX - held : 0;
    return rest > missing ? rest : missing;
}
