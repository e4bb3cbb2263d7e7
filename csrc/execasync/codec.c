/* Exec async DLE framing: execAsyncBufferOut / execAsyncByteIn.
 * Sans-I/O: bytes in, bytes out, all progress in the caller's state. */
#include "exec_async.h"

#include <stdint.h>

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
