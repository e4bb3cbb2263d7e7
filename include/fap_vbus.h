/* fap_vbus.h - a virtual 2-wire RS-485 bus made of pseudo-terminals.
 *
 * N ports, each a pty whose slave side a node opens like a serial device.
 * Every byte written on one port is delivered to every other port (and back
 * to the sender when echo is on). A relay thread does the copying; with a
 * baud rate set, delivery is paced at 10 bits per byte and overlapping
 * transmissions from two ports are a collision: both arrive corrupted.
 * Faults (bit errors, drops, silence, disconnects) are seeded and
 * reproducible. Used by tests, demos (`fap bus`) and benchmarks.
 *
 * Port paths are symlinks (in options.link_dir, or a private temp dir) that
 * stay valid across a simulated disconnect. A port nobody has open receives
 * nothing (bytes are not kept for a later opener). Collided bytes arrive
 * bit-inverted. Details, capture file format: docs/vbus.md.
 * Return convention: 0 / count, or a negative errno.
 */
#ifndef FAP_VBUS_H
#define FAP_VBUS_H

#include <stdint.h>

#include "fap_port.h"   /* fap_port_rt */

#ifdef __cplusplus
extern "C" {
#endif

#define FAP_VBUS_MAX_PORTS 64

typedef struct fap_vbus_options {
    unsigned n_ports;          /* 2..FAP_VBUS_MAX_PORTS */
    unsigned baud;             /* 0 = unpaced (as fast as ptys go) */
    int echo;                  /* also deliver each byte back to its sender */
    const char *link_dir;      /* directory for the port symlinks (NULL = temp dir) */
    const char *capture_path;  /* record every byte here (NULL = no capture) */
    uint64_t seed;             /* seed of every random fault */
    /* appended: the relay thread's real-time settings (docs/realtime.md),
     * applied by the relay as it starts; fap_vbus_open fails with the
     * refusal's code (FAP_PORT_ERTPRIV ...). Default all off. */
    fap_port_rt rt;
} fap_vbus_options;

typedef struct fap_vbus_stats {
    uint64_t bytes_in;         /* bytes written by nodes */
    uint64_t bytes_out;        /* bytes delivered to nodes */
    uint64_t collisions;       /* overlapping transmissions (paced mode) */
    uint64_t bit_errors;       /* bytes corrupted by fault injection */
    uint64_t dropped;          /* bytes dropped by fault injection or silence */
    /* appended: */
    uint64_t overflow;         /* bytes not delivered: a node's queue was full (it does not read) */
    uint64_t disconnects;      /* simulated disconnects so far */
    /* paced mode: how late the relay handed bytes over, against the end of
     * their wire time (the pacer's own jitter, without the reader's) */
    uint64_t paced_bytes;      /* bytes delivered by the pacer */
    uint64_t pace_late_sum_ns; /* their total lateness */
    uint64_t pace_late_max_ns; /* the worst one */
} fap_vbus_stats;

typedef struct fap_vbus fap_vbus;

void fap_vbus_options_init(fap_vbus_options *o);
/* Create the ptys and symlinks and start the relay thread. */
int fap_vbus_open(fap_vbus **out, const fap_vbus_options *o);
/* Stop the thread, close the ptys, remove the symlinks. NULL accepted. */
void fap_vbus_close(fap_vbus *bus);

unsigned fap_vbus_port_count(const fap_vbus *bus);
/* Stable path (symlink) of port i, or NULL if i is out of range. */
const char *fap_vbus_port_path(const fap_vbus *bus, unsigned i);

/* Random faults on bytes SENT by port i (i = -1: every port):
 * each byte has bit_error_rate chance to get one random bit flipped and
 * drop_rate chance to vanish. 0 disables. */
int fap_vbus_set_fault(fap_vbus *bus, int port, double bit_error_rate, double drop_rate);
/* Deterministic faults on the next n bytes sent by port i. */
int fap_vbus_drop_next(fap_vbus *bus, unsigned port, unsigned n);
int fap_vbus_corrupt_next(fap_vbus *bus, unsigned port, unsigned n);
/* Port i goes silent (its bytes are dropped, it hears nothing) for ms. */
int fap_vbus_silence(fap_vbus *bus, unsigned port, unsigned ms);
/* Port i disconnects for ms: its node sees a hangup (EIO), then the port
 * comes back at the same path. */
int fap_vbus_disconnect(fap_vbus *bus, unsigned port, unsigned ms);

void fap_vbus_get_stats(const fap_vbus *bus, fap_vbus_stats *out);

#ifdef __cplusplus
}
#endif
#endif /* FAP_VBUS_H */
