/* mikroC RS-485 master/slave node: who a frame is for, and how it lands in
 * the vendor's receive buffer. Sans-I/O: bytes in, buffer and flags out. */
#include <string.h>

#include "mikroc_rs485.h"
#include "mikroc/mikroc_internal.h"
#include "fap_port.h"

void mikrocRS485_CtxInitMaster(mikrocRS485_ctx *c)
{
    memset(c, 0, sizeof *c);
    c->role = MIKROC_RS485_ROLE_MASTER;
}

void mikrocRS485_CtxInitSlave(mikrocRS485_ctx *c, uint8_t address)
{
    memset(c, 0, sizeof *c);
    c->role = MIKROC_RS485_ROLE_SLAVE;
    c->address = address;
}

/* Address rule: the master hears every slave; a slave hears its own address
 * and broadcast 50, except slaves at 150 and 169 (vendor rule). */
static int accepts_address(const mikrocRS485_ctx *c, uint8_t address)
{
    if (c->role == MIKROC_RS485_ROLE_MASTER)
        return 1;
    if (address == c->address)
        return 1;
    return address == MIKROC_RS485_BROADCAST && c->address != 150 && c->address != 169;
}

/* Frames travel master -> slave (DATALEN bit 7 set) or slave -> master. */
static int right_direction(const mikrocRS485_ctx *c, uint8_t datalen)
{
    int from_master = (datalen & MIKROC_RS485_DL_MASTER) != 0;
    return c->role == MIKROC_RS485_ROLE_MASTER ? !from_master : from_master;
}

/* A damaged frame is ours when the fields that say who it is for (those that
 * arrived) match: the address, and the direction bit once DATALEN arrived.
 * Damage that hit those fields makes the frame nobody's. */
static int damaged_frame_is_ours(const mikrocRS485_ctx *c, const mikrocRS485_frame *f)
{
    if (f->header < 1 || !accepts_address(c, f->address))
        return 0;
    return f->header < 2 || right_direction(c, f->datalen);
}

static void deliver(mikrocRS485_ctx *c, char *buf, const mikrocRS485_frame *f)
{
    if ((uint8_t)buf[MIKROC_RS485_IDX_READY] == MIKROC_RS485_FLAG_SET) {
        /* The application has not taken the last message: keep it. */
        buf[MIKROC_RS485_IDX_ERROR] = (char)MIKROC_RS485_FLAG_SET;
        c->stats.overruns++;
        c->stats.errors++;
        c->stats.last_rx_error = MIKROC_RS485_EOVERRUN;
        return;
    }
    for (unsigned i = 0; i < MIKROC_RS485_MAX_DATA; i++)
        buf[i] = (char)(i < f->count ? f->data[i] : 0);
    buf[MIKROC_RS485_IDX_COUNT] = (char)f->count;
    if (c->role == MIKROC_RS485_ROLE_MASTER)
        buf[MIKROC_RS485_IDX_ADDRESS] = (char)f->address;
    buf[MIKROC_RS485_IDX_READY] = (char)MIKROC_RS485_FLAG_SET;
    c->stats.frames++;
    c->stats.last_address = f->address;
}

void mikrocRS485_CtxReceiveByte(mikrocRS485_ctx *c, char *data_buffer, uint8_t byte)
{
    if (c->role == MIKROC_RS485_ROLE_NONE || !data_buffer)
        return;
    mikrocRS485_frame f;
    /* what the decoder holds before this byte: the frame's raw bytes if it ends */
    uint8_t raw[2 + sizeof c->dec.raw];
    size_t held = 0;
    if (c->trace && c->dec.in_frame) {
        raw[held++] = MIKROC_RS485_START_BYTE;
        memcpy(raw + held, c->dec.raw, c->dec.n);
        held += c->dec.n;
    }
    int r = mikrocRS485_DecoderFeed(&c->dec, byte, &f);
    if (r == MIKROC_RS485_MORE)
        return;
    if (c->trace && held) {
        if (r != MIKROC_RS485_EABORT)   /* a start byte belongs to the next frame */
            raw[held++] = byte;
        lf_mikroc_trace(c, FAP_TRACE_RX, r == MIKROC_RS485_FRAME ? FAP_TRACE_OK :
                        r == MIKROC_RS485_ECRC ? FAP_TRACE_BAD_CRC :
                        r == MIKROC_RS485_EABORT ? FAP_TRACE_TRUNCATED : FAP_TRACE_BAD_FRAME,
                        raw, held);
    }
    if (r == MIKROC_RS485_FRAME) {
        if (right_direction(c, f.datalen) && accepts_address(c, f.address))
            deliver(c, data_buffer, &f);
        else
            c->stats.ignored++;
        return;
    }
    c->stats.damaged++;
    if (damaged_frame_is_ours(c, &f)) {
        data_buffer[MIKROC_RS485_IDX_ERROR] = (char)MIKROC_RS485_FLAG_SET;
        c->stats.errors++;
        c->stats.last_rx_error = r;
    }
}

void lf_mikroc_trace(mikrocRS485_ctx *c, fap_trace_dir dir, fap_trace_status status,
                     const uint8_t *data, size_t len)
{
    fap_trace_frame fr = {.dir = dir, .status = status, .t_ns = fap_port_now_ns(),
                          .data = data, .len = len};
    c->trace(c->trace_ctx, &fr);
}

void mikrocRS485_CtxSetTrace(mikrocRS485_ctx *c, fap_trace_fn fn, void *ctx)
{
    if (!c)
        return;
    c->trace = fn;
    c->trace_ctx = ctx;
}

void mikrocRS485_CtxGetStats(const mikrocRS485_ctx *c, mikrocRS485_stats *out)
{
    if (!c || !out)
        return;
    *out = c->stats;
}

const char *mikrocRS485_strerror(int code)
{
    switch (code) {
    case 0: return "no error";
    case MIKROC_RS485_ECRC: return "mikroC frame: checksum mismatch";
    case MIKROC_RS485_EFORMAT: return "mikroC frame: bad DATALEN or escape flags";
    case MIKROC_RS485_ESHORT: return "mikroC frame: stop byte too early";
    case MIKROC_RS485_ELONG: return "mikroC frame: no stop byte where expected (too long)";
    case MIKROC_RS485_EABORT: return "mikroC frame: cut off by a new start byte";
    case MIKROC_RS485_EOVERRUN: return "mikroC frame: not stored, ready flag still set (overrun)";
    default: return fap_port_strerror(code);
    }
}
