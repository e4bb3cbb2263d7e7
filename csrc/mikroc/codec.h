/* A monitor's view of the mikroC decoder: mikrocRS485_DecoderFeed over a
 * byte run, with the stream span of each reported frame (good or bad) and
 * a short reason. Sans-I/O; the receiver's rules stay in mikroc/codec.c. */
#ifndef LF_MIKROC_SCAN_H
#define LF_MIKROC_SCAN_H
#include <stddef.h>
#include <stdint.h>

#include "mikroc_rs485.h"

typedef struct lf_mikroc_scan {
    mikrocRS485_decoder d;
    mikrocRS485_frame f;             /* the last report's frame (or partial) */
    int code;                        /* last report: FRAME or a MIKROC_RS485_E* */
    const char *reason;              /* its short reason, NULL for FRAME */
    uint64_t pos;                    /* stream offset of the next byte */
    uint64_t start;                  /* offset of the current frame's start byte */
    uint64_t rep_start, rep_end;     /* span [start, end) of the last report */
} lf_mikroc_scan;

void lf_mikroc_scan_init(lf_mikroc_scan *s);
/* Feed bytes until the decoder reports (code != MORE) or p runs out;
 * returns the bytes consumed. An EABORT span ends before the start byte
 * that cut it off. */
size_t lf_mikroc_scan_feed(lf_mikroc_scan *s, const uint8_t *p, size_t n);
/* True while a frame is in progress (its bytes are in [start, pos)). */
int lf_mikroc_scan_in_frame(const lf_mikroc_scan *s);
#endif
