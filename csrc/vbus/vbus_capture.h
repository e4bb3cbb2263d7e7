/* vbus_capture.h - the capture file of the virtual bus (format: docs/vbus.md).
 *
 * Line oriented text, one line per run of back-to-back bytes a port put on
 * the wire (at most LF_CAPTURE_BYTES_PER_LINE):
 *     <t_us> <port> <hex byte> <hex byte> ...
 * and event lines starting with '#':
 *     # fap-vbus-capture 1 ports=N baud=B echo=E seed=S
 *     # collision t=<t_us> ports=A,B
 *     # fault t=<t_us> port=P reason=<name> n=<count>
 *     # overflow t=<t_us> port=P n=<count>
 *     # silence|disconnect t=<t_us> port=P ms=<ms>
 *     # reconnect t=<t_us> port=P
 *     # end t=<t_us> bytes_in=... bytes_out=... collisions=... bit_errors=... dropped=...
 * t_us is microseconds since the bus opened (CLOCK_MONOTONIC).
 */
#ifndef LF_VBUS_CAPTURE_H
#define LF_VBUS_CAPTURE_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include "common/mono_clock.h"

#define LF_CAPTURE_BYTES_PER_LINE 64
/* Flush at most this long after the first unflushed line, so a monitor
 * tailing the file sees traffic without a syscall per line. */
#define LF_CAPTURE_FLUSH_NS (50 * LF_NS_PER_MS)

typedef struct lf_capture {
    FILE *f;
    lf_ns t0;           /* bus open time */
    lf_ns char_ns;      /* paced: a split line's next part starts n char times later */
    lf_ns dirty_since;  /* LF_NEVER when everything is flushed */
    int error;          /* first write error (positive errno), sticky */
    /* The data line being built: paced bytes arrive one timer tick at a
     * time; back-to-back bytes of one sender join one line. */
    unsigned line_port;
    lf_ns line_t, line_next;   /* start of the line; where a continuation starts */
    size_t line_n;
    uint8_t line[LF_CAPTURE_BYTES_PER_LINE];
} lf_capture;

/* Create/truncate path and write the header line. Returns 0 or -errno. */
int lf_capture_open(lf_capture *c, const char *path, lf_ns t0, unsigned n_ports,
                    unsigned baud, int echo, uint64_t seed);
void lf_capture_data(lf_capture *c, lf_ns t, unsigned port, const uint8_t *data, size_t n);
/* An event line: "# <kind> t=<t_us> <fmt...>". */
void lf_capture_event(lf_capture *c, lf_ns t, const char *kind, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
/* When lf_capture_tick() has work: a data line whose sender went quiet,
 * or buffered lines older than LF_CAPTURE_FLUSH_NS. LF_NEVER if none. */
lf_ns lf_capture_due(const lf_capture *c);
void lf_capture_tick(lf_capture *c, lf_ns now);
/* Flush and close. Returns 0 or the first write error as -errno. */
int lf_capture_close(lf_capture *c);

#endif
