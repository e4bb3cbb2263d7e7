/* Exec async DLE framing: execAsyncBufferOut / execAsyncByteIn.
 * Sans-I/O: bytes in, bytes out, all progress in the caller's state. */
#include "exec_async.h"

#include <stdint.h>
#include <string.h>

#include "common/crc16.h"
#include "execasync/codec_internal.h"

enum rx_phase {
    PH_HUNT = 0,      /* zero-filled state: waiting for DLE */
    PH_HUNT_DLE,      /* DLE seen, STX starts a frame */
    PH_NODE,          /* next byte is the raw node number */
    PH_SEQ,           /* next byte is the raw sequence number */
    PH_DATA,
    PH_DATA_DLE,      /* DLE inside the data: DLE, ETX or STX follows */
    PH_CRC_HI,
    PH_CRC_LO,
    PH_SKIP,          /* rest of an overflowed frame */
    PH_SKIP_DLE,
    PH_SKIP_CRC_HI,
    PH_SKIP_CRC_LO
};

static inline uint16_t crc_byte(uint16_t crc, byte b)
{
    return lf_crc16_arc_update(crc, &b, 1);
}

word execAsyncBufferOut(byte Node, byte *Raw, byte *TxBuf, byte RawSize, byte SeqNo)
{
    word n = 0;
    TxBuf[n++] = EXEC_ASYNC_DLE;
    TxBuf[n++] = EXEC_ASYNC_STX;
    TxBuf[n++] = Node;              /* raw, even when it is a DLE */
    TxBuf[n++] = SeqNo;
    for (unsigned i = 0; i < RawSize; i++) {
        if (Raw[i] == EXEC_ASYNC_DLE)
            TxBuf[n++] = EXEC_ASYNC_DLE;
        TxBuf[n++] = Raw[i];
    }
    /* CRC over everything as sent between DLE STX and DLE ETX */
    uint16_t crc = lf_crc16_arc(TxBuf + 2, (size_t)n - 2);
    TxBuf[n++] = EXEC_ASYNC_DLE;
    TxBuf[n++] = EXEC_ASYNC_ETX;
    TxBuf[n++] = (byte)(crc >> 8);  /* big-endian, not stuffed */
    TxBuf[n++] = (byte)(crc & 0xFF);
    return n;
}

/* Report a finished (or broken) frame; the caller returns true. */
static boolean report(struct execAsyncStateDef *s, byte status, byte next_phase)
{
    s->Status = status;
    s->Phase = next_phase;
    return TRUE;
}

/* DLE STX seen. Length and Crc restart with the node byte, so a FRAMING
 * report made at this STX still shows the cut frame's Length. */
static void start_frame(struct execAsyncStateDef *s)
{
    s->Phase = PH_NODE;
}

boolean execAsyncByteIn(byte Value, struct execAsyncStateDef *State, byte *Buffer)
{
    struct execAsyncStateDef *s = State;
    unsigned cap = s->BufferSize ? s->BufferSize : EXEC_ASYNC_MAX_DATA;

    s->Status = EXEC_ASYNC_NONE;    /* the previous report has been consumed */
    switch (s->Phase) {
    case PH_HUNT:
        if (Value == EXEC_ASYNC_DLE)
            s->Phase = PH_HUNT_DLE;
        return FALSE;
    case PH_HUNT_DLE:
        if (Value == EXEC_ASYNC_STX)
            start_frame(s);
        else if (Value != EXEC_ASYNC_DLE)   /* DLE DLE: the second may start a frame */
            s->Phase = PH_HUNT;
        return FALSE;
    case PH_NODE:
        s->Node = Value;
        s->Length = 0;
        s->Crc = crc_byte(0, Value);
        s->Phase = PH_SEQ;
        return FALSE;
    case PH_SEQ:
        s->SeqNo = Value;
        s->Crc = crc_byte(s->Crc, Value);
        s->Phase = PH_DATA;
        return FALSE;
    case PH_DATA:
        if (Value == EXEC_ASYNC_DLE) {
            s->Phase = PH_DATA_DLE;
            return FALSE;
        }
        break;                              /* store below */
    case PH_DATA_DLE:
        if (Value == EXEC_ASYNC_ETX) {
            s->Phase = PH_CRC_HI;
            return FALSE;
        }
        if (Value == EXEC_ASYNC_STX) {      /* a new frame cut this one short */
            return report(s, EXEC_ASYNC_FRAMING, PH_NODE);
        }
        if (Value != EXEC_ASYNC_DLE)
            return report(s, EXEC_ASYNC_FRAMING, PH_HUNT);
        s->Crc = crc_byte(s->Crc, EXEC_ASYNC_DLE);  /* the stuffing DLE */
        s->Phase = PH_DATA;
        break;                              /* store the data DLE below */
    case PH_CRC_HI:
        s->CrcHigh = Value;
        s->Phase = PH_CRC_LO;
        return FALSE;
    case PH_CRC_LO: {
        uint16_t rx = (uint16_t)((s->CrcHigh << 8) | Value);
        return report(s, rx == s->Crc ? EXEC_ASYNC_GOOD : EXEC_ASYNC_BAD_CRC, PH_HUNT);
    }
    case PH_SKIP:
        if (Value == EXEC_ASYNC_DLE)
            s->Phase = PH_SKIP_DLE;
        return FALSE;
    case PH_SKIP_DLE:
        if (Value == EXEC_ASYNC_ETX)
            s->Phase = PH_SKIP_CRC_HI;
        else if (Value == EXEC_ASYNC_STX)
            start_frame(s);
        else
            s->Phase = Value == EXEC_ASYNC_DLE ? PH_SKIP : PH_HUNT;
        return FALSE;
    case PH_SKIP_CRC_HI:
        s->Phase = PH_SKIP_CRC_LO;
        return FALSE;
    case PH_SKIP_CRC_LO:
    default:                                /* a corrupted state: resynchronise */
        s->Phase = PH_HUNT;
        return FALSE;
    }

    /* a data byte (unstuffed) */
    s->Crc = crc_byte(s->Crc, Value);
    if (s->Length >= cap)
        return report(s, EXEC_ASYNC_OVERFLOW, PH_SKIP);
    Buffer[s->Length++] = Value;
    return FALSE;
}

int lf_exec_rx_in_frame(const struct execAsyncStateDef *s)
{
    return s->Phase >= PH_NODE && s->Phase <= PH_CRC_LO;  /* not the skip of a reported overflow */
}

/* ---- trace tap: the bytes of the frame in progress ---- */

static void tap_add(lf_exec_tap *t, byte v)
{
    if (t->n < sizeof t->raw)
        t->raw[t->n++] = v;
}

static fap_trace_status trace_status(byte status)
{
    switch (status) {
    case EXEC_ASYNC_GOOD: return FAP_TRACE_OK;
    case EXEC_ASYNC_BAD_CRC: return FAP_TRACE_BAD_CRC;
    case EXEC_ASYNC_OVERFLOW: return FAP_TRACE_TRUNCATED;
    default: return FAP_TRACE_BAD_FRAME;
    }
}

boolean lf_exec_byte_in_traced(byte v, struct execAsyncStateDef *s, byte *buf,
                               lf_exec_tap *t, lf_trace *tr, int64_t now)
{
    byte before = s->Phase;
    boolean done = execAsyncByteIn(v, s, buf);
    if (!lf_trace_on(tr)) {
        t->n = 0;
        t->reported = 0;
        return done;
    }
    if (t->reported) {             /* the last frame was reported: start afresh */
        t->n = 0;
        if (t->restart) {
            tap_add(t, EXEC_ASYNC_DLE);
            tap_add(t, EXEC_ASYNC_STX);
        }
        t->reported = t->restart = 0;
    }
    if (before == PH_HUNT)
        t->n = 0;                  /* noise between frames is not kept */
    tap_add(t, v);
    if (done) {
        /* a DLE STX that cut this frame short belongs to the next one */
        t->restart = s->Phase == PH_NODE;
        size_t len = t->restart && t->n >= 2 ? t->n - 2 : t->n;
        lf_trace_emit(tr, FAP_TRACE_RX, trace_status(s->Status), now, t->raw, len);
        t->reported = 1;
    } else if (s->Phase == PH_HUNT) {
        t->n = 0;
    } else if (s->Phase == PH_HUNT_DLE) {
        t->n = 0;
        tap_add(t, EXEC_ASYNC_DLE);
    }
    return done;
}

void lf_exec_tap_abandon(lf_exec_tap *t, lf_trace *tr, int64_t now)
{
    if (!t->reported && t->n > 1 && lf_trace_on(tr))   /* a lone DLE is no frame */
        lf_trace_emit(tr, FAP_TRACE_RX, FAP_TRACE_TRUNCATED, now, t->raw, t->n);
    t->n = 0;
    t->reported = t->restart = 0;
}

void lf_exec_scan_init(lf_exec_scan *s)
{
    memset(s, 0, sizeof *s);
}

size_t lf_exec_scan_feed(lf_exec_scan *s, const byte *p, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        uint64_t at = s->pos++;
        if (!execAsyncByteIn(p[i], &s->st, s->buf)) {
            if (s->st.Phase == PH_NODE)         /* this byte was the STX of DLE STX */
                s->start = at - 1;
            continue;
        }
        s->rep_start = s->start;
        if (s->st.Status == EXEC_ASYNC_FRAMING && s->st.Phase == PH_NODE) {
            s->rep_end = at - 1;                /* cut by the DLE STX at at-1 */
            s->start = at - 1;
        } else {
            s->rep_end = at + 1;
        }
        return i + 1;
    }
    return n;
}

const char *lf_exec_status_reason(int status)
{
    switch (status) {
    case EXEC_ASYNC_BAD_CRC:  return "crc";
    case EXEC_ASYNC_OVERFLOW: return "length";
    case EXEC_ASYNC_FRAMING:  return "framing";
    default:                  return NULL;
    }
}

size_t lf_exec_rx_missing(const struct execAsyncStateDef *s)
{
    /* the fewest bytes that can end a frame from each phase:
     * DLE STX node seq [data] DLE ETX crc crc */
    static const unsigned char left[] = {
        [PH_HUNT] = 8, [PH_HUNT_DLE] = 7, [PH_NODE] = 6, [PH_SEQ] = 5,
        [PH_DATA] = 4, [PH_DATA_DLE] = 3, [PH_CRC_HI] = 2, [PH_CRC_LO] = 1,
        [PH_SKIP] = 4, [PH_SKIP_DLE] = 3, [PH_SKIP_CRC_HI] = 2, [PH_SKIP_CRC_LO] = 1,
    };
    return s->Phase < sizeof left ? left[s->Phase] : 1;
}

void lf_exec_flen_byte(lf_exec_flen *f, const struct execAsyncStateDef *s, int was_in, int done)
{
    if (done) {
        f->last = f->cur + 1 <= EXEC_ASYNC_MAX_FRAME ? f->cur + 1 : 0;
        f->cur = lf_exec_rx_in_frame(s) ? 2 : 0;   /* a DLE STX cut it short */
    } else if (lf_exec_rx_in_frame(s)) {
        f->cur = was_in ? f->cur + 1 : 2;           /* DLE STX: 2 bytes in */
    } else {
        f->cur = 0;
    }
}

size_t lf_exec_rx_want(const struct execAsyncStateDef *s, const lf_exec_flen *f, size_t expect)
{
    size_t want = lf_exec_rx_missing(s);
    return expect > f->cur && expect - f->cur > want ? expect - f->cur : want;
}
