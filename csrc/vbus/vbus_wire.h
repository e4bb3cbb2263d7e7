/* vbus_wire.h - the sans-I/O model of the virtual RS-485 wire.
 *
 * It takes the bytes each port sent (with the time the relay read them) and
 * decides what every port receives and when: fault injection (seeded PRNG
 * per port), pacing at 10 bits per byte, collisions between overlapping
 * transmissions. It never touches an fd; the relay (vbus.c) feeds it bytes
 * and a clock and writes out what the sink callbacks hand back.
 *
 * Unpaced (char_ns == 0): lf_wire_send() delivers at once, in place.
 * Paced: every sender has a FIFO of bytes with their wire start times;
 * lf_wire_advance(now) delivers the bytes whose wire time has ended, in
 * wire order, and lf_wire_next_due() tells the relay when to come back.
 */
#ifndef LF_VBUS_WIRE_H
#define LF_VBUS_WIRE_H

#include <stddef.h>
#include <stdint.h>
#include "common/mono_clock.h"

#define LF_WIRE_MAX_PORTS 64
/* Paced mode: bytes per sender on the wire or waiting for it. When full the
 * relay stops reading that port, so the node's write blocks like a UART's. */
#define LF_WIRE_PENDING_CAP 4096
/* Longest run handed to deliver() in paced mode. */
#define LF_WIRE_RUN_MAX 256

/* Why a byte did not reach the wire intact (capture and stats). */
typedef enum lf_wire_reason {
    LF_WIRE_SILENCE = 0,      /* sender silenced: dropped */
    LF_WIRE_DROP_NEXT,        /* fap_vbus_drop_next: dropped */
    LF_WIRE_DROP_RATE,        /* random drop: dropped */
    LF_WIRE_CORRUPT_NEXT,     /* fap_vbus_corrupt_next: one bit flipped */
    LF_WIRE_BIT_ERROR,        /* random bit error: one bit flipped */
    LF_WIRE_REASON_COUNT
} lf_wire_reason;

const char *lf_wire_reason_name(lf_wire_reason r);

typedef struct lf_wire_sink {
    void *ctx;
    /* n bytes sent by `sender` are complete on the wire: hand them to every
     * port whose bit is set in `to` (possibly none). t: wire start of data[0] (unpaced: the
     * time the relay read it). */
    void (*deliver)(void *ctx, unsigned sender, uint64_t to, const uint8_t *data,
                    size_t n, lf_ns t);
    /* transmissions of ports a and b overlap from time t on (counted once
     * per pair of bursts). */
    void (*collision)(void *ctx, unsigned a, unsigned b, lf_ns t);
    /* n bytes sent by `port` were dropped or corrupted for `reason`. */
    void (*fault)(void *ctx, unsigned port, lf_wire_reason reason, size_t n, lf_ns t);
} lf_wire_sink;

typedef struct lf_wire_stats {
    uint64_t bytes_in;
    uint64_t collisions;
    uint64_t bit_errors;
    uint64_t dropped;
    uint64_t paced_bytes;       /* delivered by lf_wire_advance */
    uint64_t late_sum_ns;       /* sum of (now - end of wire time) over them */
    uint64_t late_max_ns;
} lf_wire_stats;

typedef struct lf_wire_byte {
    lf_ns begin;              /* wire start; it ends at begin + char_ns */
    uint8_t value;
    uint8_t flags;            /* LF_WIRE_F_* */
} lf_wire_byte;

typedef struct lf_wire_port {
    double bit_error_rate, drop_rate;
    unsigned drop_next, corrupt_next;
    lf_ns silent_until;       /* silenced while now < silent_until */
    int connected;            /* receives only when connected */
    uint64_t rng;             /* splitmix64 state, seeded per port */
    /* paced only */
    lf_wire_byte *fifo;       /* ring of LF_WIRE_PENDING_CAP */
    size_t head, count;
    lf_ns wire_end;           /* end of this sender's last byte on the wire */
    uint64_t collided_with;   /* ports this burst already collided with */
} lf_wire_port;

typedef struct lf_wire {
    unsigned n_ports;
    lf_ns char_ns;            /* 0 = unpaced */
    int echo;
    lf_wire_sink sink;
    lf_wire_stats stats;
    lf_wire_port port[LF_WIRE_MAX_PORTS];
} lf_wire;

/* baud 0 = unpaced. Returns 0, -EINVAL or -ENOMEM. */
int lf_wire_init(lf_wire *w, unsigned n_ports, unsigned baud, int echo, uint64_t seed,
                 const lf_wire_sink *sink);
void lf_wire_free(lf_wire *w);

/* How many more bytes port p may send now (SIZE_MAX when unpaced). */
size_t lf_wire_space(const lf_wire *w, unsigned p);
/* Port p sent data[0..n) (n <= space), read at `now`. data is modified
 * (faults are applied in place). */
void lf_wire_send(lf_wire *w, unsigned p, uint8_t *data, size_t n, lf_ns now);
/* Paced: deliver every byte whose wire time ended at or before now. */
void lf_wire_advance(lf_wire *w, lf_ns now);
/* Earliest time a pending byte ends on the wire, LF_NEVER if none. */
lf_ns lf_wire_next_due(const lf_wire *w);
/* Ports that hear a byte sent by `sender` at time now. */
uint64_t lf_wire_receivers(const lf_wire *w, unsigned sender, lf_ns now);

/* Fault controls (port < n_ports; the caller validates). */
void lf_wire_set_rates(lf_wire *w, unsigned p, double bit_error_rate, double drop_rate);
void lf_wire_drop_next(lf_wire *w, unsigned p, unsigned n);
void lf_wire_corrupt_next(lf_wire *w, unsigned p, unsigned n);
void lf_wire_silence(lf_wire *w, unsigned p, lf_ns until);
void lf_wire_set_connected(lf_wire *w, unsigned p, int connected);

#endif
