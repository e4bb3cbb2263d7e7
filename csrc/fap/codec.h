/* FAP wire frames: encoder and streaming decoder (sans-I/O).
 *
 * Frame: marker "cCtRsFeF" | size u16 LE (13 + data length) | msg u8 |
 * dst u8 | src u8 | data 0..1024 | CRC-16/CCITT-FALSE u16 LE over
 * size..data. Receivers also accept the marker spelling "cCtRsFef".
 * The decoder takes bytes in any chunking plus the current time, and
 * reports complete, valid frames through a callback. It never touches an
 * fd; the engine feeds it. */
#ifndef LF_FAP_FRAME_H
#define LF_FAP_FRAME_H
#include <stddef.h>
#include <stdint.h>
#include "common/mono_clock.h"

#define LF_FAP_MARKER      "cCtRsFeF"
#define LF_FAP_MARKER_LEN  8
#define LF_FAP_HDR_LEN     13            /* marker + size + msg + dst + src */
#define LF_FAP_MSG_AT      10            /* the message type's byte: after marker + size */
#define LF_FAP_CRC_LEN     2
#define LF_FAP_OVERHEAD    (LF_FAP_HDR_LEN + LF_FAP_CRC_LEN)   /* 15 */
#define LF_FAP_MAX_DATA    1024
#define LF_FAP_MAX_FRAME   (LF_FAP_OVERHEAD + LF_FAP_MAX_DATA) /* 1039 */
#define LF_FAP_MAX_ID      31

enum lf_fap_msg {
    LF_FAP_SEND_DATA = 0,
    LF_FAP_DATA      = 1,
    LF_FAP_DATA_DONE = 2,
    LF_FAP_QUERY_ID  = 3,
    LF_FAP_ID        = 4
};

typedef struct lf_fap_frame {
    uint8_t  msg, dst, src;
    uint16_t len;                        /* data length */
    const uint8_t *data;                 /* points into the decoder's buffer */
    const uint8_t *raw;                  /* the whole frame as received (marker..CRC) */
    size_t raw_len;
    uint64_t offset;                     /* stream offset of raw[0] (bytes fed before it) */
} lf_fap_frame;

/* Encode one frame into out (cap >= 15 + len). Returns the frame length,
 * or 0 when the message is invalid: msg > 4, DATA with len 0 or > 1024,
 * another message with data. */
size_t lf_fap_encode(uint8_t *out, size_t cap, unsigned msg, unsigned dst,
                     unsigned src, const uint8_t *data, size_t len);

/* Receive counters (cumulative). */
typedef struct lf_fap_rx_counts {
    uint64_t bytes;          /* bytes fed */
    uint64_t frames;         /* valid frames reported */
    uint64_t crc_errors;     /* complete frame, CRC mismatch */
    uint64_t framing_errors; /* marker ok, bad size or msg/size mismatch */
    uint64_t gap_timeouts;   /* partial frame abandoned after the inter-byte gap */
    uint64_t garbage_bytes;  /* bytes skipped while searching for a marker */
} lf_fap_rx_counts;

typedef void (*lf_fap_frame_cb)(void *ctx, const lf_fap_frame *f, lf_ns now);

/* Why the decoder dropped bytes (reported to an optional reject callback,
 * for a monitor; the counters above count the same events). */
enum lf_fap_reject {
    LF_FAP_REJ_GARBAGE = 1,  /* bytes skipped while searching for a marker */
    LF_FAP_REJ_SIZE,         /* size field outside 13..1037 */
    LF_FAP_REJ_MSG,          /* msg above ID (4) */
    LF_FAP_REJ_MSG_SIZE,     /* DATA without data, or another msg with data */
    LF_FAP_REJ_CRC,          /* complete frame, CRC mismatch */
    LF_FAP_REJ_GAP           /* partial frame abandoned after the inter-byte gap */
};
/* raw/n: the rejected bytes (a candidate frame from its marker: the header
 * up to the bad field, the whole frame for CRC, the held partial for GAP;
 * the skipped run for GARBAGE); offset: stream offset of raw[0]. A
 * rejected candidate loses only its first byte, so its later bytes are
 * scanned again and may be reported again (as GARBAGE or inside a frame). */
typedef void (*lf_fap_reject_cb)(void *ctx, int reason, const uint8_t *raw, size_t n,
                                 uint64_t offset, lf_ns now);

typedef struct lf_fap_decoder {
    uint8_t buf[LF_FAP_MAX_FRAME];
    size_t  n;               /* bytes held (a candidate frame prefix) */
    lf_ns   last_byte;       /* arrival time of the newest held byte */
    lf_ns   gap;             /* inter-byte gap that abandons a partial frame */
    lf_fap_rx_counts c;
    uint64_t pos;            /* stream offset of buf[0] */
    lf_fap_reject_cb reject; /* optional, NULL after init */
    void   *reject_ctx;
} lf_fap_decoder;

/* Inter-byte gap default: the longer of 4 character times and 10 ms. */
lf_ns lf_fap_default_gap(unsigned baud);

void lf_fap_decoder_init(lf_fap_decoder *d, lf_ns gap);
/* Feed n bytes that arrived at `now`; every valid frame completed by them
 * is reported through cb (frame data is valid during the call only).
 * Feeding never applies the inter-byte gap: a driver that was itself
 * late to read cannot tell when the bytes really arrived, so the gap is
 * judged only by lf_fap_decoder_tick(), called when the line is idle (no
 * bytes waiting). A late continuation is still safe: a wrong candidate
 * fails its size/msg/CRC checks and the search resumes at its 2nd byte. */
void lf_fap_decoder_feed(lf_fap_decoder *d, const uint8_t *p, size_t n, lf_ns now,
                         lf_fap_frame_cb cb, void *ctx);
/* When a partial frame will be abandoned (LF_NEVER if none is held). */
lf_ns lf_fap_decoder_deadline(const lf_fap_decoder *d);
/* Apply the inter-byte gap at `now`: abandon a stale partial frame and
 * rescan what followed its first byte (which may hold a complete frame). */
void lf_fap_decoder_tick(lf_fap_decoder *d, lf_ns now, lf_fap_frame_cb cb, void *ctx);
/* How many more bytes the held candidate frame needs at least: exact once
 * its size field is in, the minimal frame before that; 0 when nothing is
 * held. The engine sleeps their wire time instead of waking per byte. */
size_t lf_fap_decoder_missing(const lf_fap_decoder *d);
/* The message type of the held candidate frame, or -1 before its byte is in. */
int lf_fap_decoder_msg(const lf_fap_decoder *d);
/* Drop everything held (after a port reopen). */
void lf_fap_decoder_reset(lf_fap_decoder *d);
/* Report every rejection through cb (NULL: stop reporting). */
void lf_fap_decoder_on_reject(lf_fap_decoder *d, lf_fap_reject_cb cb, void *ctx);
/* Short name of an lf_fap_reject reason ("crc", "size", ...; "?" if unknown). */
const char *lf_fap_reject_name(int reason);
#endif
