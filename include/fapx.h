/* fapx.h - libfap's re-entrant FAP handle API.
 *
 * One handle = one FAP node (master or slave) on one serial port, run by
 * its own engine thread (poll on the port fd, a timerfd and an eventfd;
 * CLOCK_MONOTONIC deadlines; no signals). Any number of handles may be open
 * in one process, e.g. a master and three slaves on four ports of one
 * virtual bus. Every call is thread-safe.
 *
 * Return convention: 0 (or a count) on success, a negative errno on failure
 * (fap_port.h codes can appear from fapx_open). fapx_strerror() names them.
 *   -EINVAL  bad argument (ID out of range, size 0 or > 1024, bad options)
 *   -EEXIST  fapx_add_slave: already listed
 *   -ENOENT  fapx_remove_slave / fapx_slave_active: not listed
 *   -EPERM   slave-list call on a slave handle
 *   -EAGAIN  tx queue full / nothing to receive / no event
 *   -ETIMEDOUT  a *_wait call reached its timeout
 *   -EMSGSIZE   fapx_rx: buffer smaller than the frame (frame kept queued)
 *   -ESHUTDOWN  the handle is closing
 * The classic vendor API (<fap.h>) runs over one default handle of this
 * kind; fapClassicHandle() / fapClassicClose() below reach it. */
#ifndef FAPX_H
#define FAPX_H

#include <stddef.h>
#include <stdint.h>
#include <fap_port.h>
#include <fap_trace.h>

#ifdef __cplusplus
extern "C" {
#endif

#define FAPX_MASTER          0       /* same values as FAP_MASTER / FAP_SLAVE */
#define FAPX_SLAVE           1
#define FAPX_MAX_ID          31      /* slave IDs 1..31; the master is 0 */
#define FAPX_MAX_DATA        1024
#define FAPX_DEFAULT_RX_DEPTH 256    /* received DATA frames held for fapx_rx */
#define FAPX_DEFAULT_TX_DEPTH 64     /* frames queued by fapx_tx, not yet sent */
#define FAPX_DEFAULT_EV_DEPTH 256    /* events held for fapx_event_get */

typedef struct fapx fapx;            /* opaque */

typedef struct fapx_options {
    unsigned mode;            /* FAPX_MASTER or FAPX_SLAVE */
    unsigned id;              /* master 0, slave 1..31 */
    /* Protocol timing, microseconds; 0 = the vendor default. */
    uint64_t idc_us;          /* ID cycle period while a slave is inactive (15 s) */
    uint64_t id_answer_us;    /* QUERY_ID -> ID window (1 s) */
    uint64_t data_done_us;    /* SEND_DATA -> DATA_DONE limit (15 s) */
    uint64_t send_budget_us;  /* sending time per turn, master slot and slave (10 s) */
    uint64_t gap_us;          /* inter-byte gap abandoning a partial frame
                                 (0 = the longer of 4 character times and 10 ms) */
    uint64_t reopen_us;       /* retry period after the port vanished (0 = 200 ms) */
    unsigned rx_depth;        /* 0 = FAPX_DEFAULT_RX_DEPTH */
    unsigned tx_depth;        /* 0 = FAPX_DEFAULT_TX_DEPTH */
    unsigned ev_depth;        /* 0 = FAPX_DEFAULT_EV_DEPTH */
    fap_port_options port;    /* baud (any termios rate; the classic API allows
                                 9600..115200), RS-485 direction mode, RTS
                                 polarity and delays, echo, turnaround */
    fap_trace_fn trace;       /* wire trace hook from the very first frame
                                 (NULL = none; see fapx_set_trace) */
    void *trace_ctx;
    int cancel_fd;            /* the open's external cancel: while fapx_open
                                 runs (name lookup, connect, RFC 2217
                                 negotiation), this fd turning readable (an
                                 eventfd written from another thread, a
                                 signal handler) ends it with -ECANCELED.
                                 Watched only during the open; the caller
                                 keeps it open until fapx_open returns.
                                 0 = none */
} fapx_options;

/* Events, read with fapx_event_get() (and optionally passed to the callback). */
typedef enum fapx_event_type {
    FAPX_EV_SLAVE_ACTIVE = 1,    /* master: slave `id` answered QUERY_ID */
    FAPX_EV_SLAVE_INACTIVE = 2,  /* master: slave `id` missed DATA_DONE (ID cycle follows) */
    FAPX_EV_ID_TIMEOUT = 3,      /* master: slave `id` did not answer QUERY_ID */
    FAPX_EV_QUERIED = 4,         /* slave: the master queried us (we answered) */
    FAPX_EV_RX = 5,              /* callback only: a DATA frame from `id` was queued */
    FAPX_EV_PORT_LOST = 6,       /* the port failed (device gone); reopen attempts follow */
    FAPX_EV_PORT_REOPENED = 7,   /* the port is back */
    FAPX_EV_RX_OVERFLOW = 8,     /* a DATA frame from `id` was dropped: rx queue full */
} fapx_event_type;

typedef struct fapx_event {
    int type;                 /* fapx_event_type */
    unsigned id;              /* slave / sender ID the event is about */
    int64_t time_ns;          /* CLOCK_MONOTONIC time of the event */
} fapx_event;

/* Optional: called from the ENGINE THREAD for every event (and FAPX_EV_RX)
 * in addition to queuing it. Keep it short; it must not call fapx_close on
 * its own handle. */
typedef void (*fapx_callback)(void *ctx, const fapx_event *ev);

typedef struct fapx_stats {
    uint64_t frames_tx, frames_rx;     /* valid frames sent / received (all types) */
    uint64_t bytes_tx, bytes_rx;       /* wire bytes */
    uint64_t data_tx, data_rx;         /* DATA frames sent / delivered to this node */
    uint64_t crc_errors;               /* complete frames with a bad CRC */
    uint64_t framing_errors;           /* bad size, msg/size mismatch */
    uint64_t gap_timeouts;             /* partial frames abandoned after the inter-byte gap */
    uint64_t garbage_bytes;            /* bytes skipped while looking for a marker */
    uint64_t id_timeouts;              /* master: QUERY_ID unanswered */
    uint64_t data_done_timeouts;       /* master: DATA_DONE missing (slave marked inactive) */
    uint64_t collisions;               /* echo mismatches reported by the port layer */
    uint64_t cycles;                   /* master: complete data cycles */
    uint64_t id_cycles;                /* master: complete ID cycles */
    uint64_t polls;                    /* SEND_DATA -> DATA_DONE turns completed */
    uint64_t rx_dropped;               /* DATA lost to a full rx queue */
    uint64_t tx_dropped;               /* queued frames discarded (destination = own ID) */
    uint64_t write_errors;             /* failed port writes */
    uint64_t port_lost, port_reopened;
    uint64_t unexpected;               /* valid frames that fit no protocol state */
    /* Losses (appended; docs/reliability.md). FAP has no acknowledgement,
     * so the master counts what it cannot have delivered: */
    uint64_t ev_dropped;               /* events lost to a full event queue (the
                                          callback still saw them) */
    uint64_t tx_to_inactive;           /* master: DATA sent to a slave that was not
                                          active (unlisted, or inactive) at the time */
    uint64_t tx_unconfirmed;           /* master: DATA sent to a slave that was then
                                          marked inactive (no DATA_DONE after it) */
    /* Appended: frames a stop (fapx_close, fapConfig) dropped because the
     * line did not take them within FAPX_STOP_GRACE_MS: the write in
     * progress, the rest of the turn and, at close, DATA still queued
     * (read with fapx_close_stats). */
    uint64_t tx_abandoned;
} fapx_stats;

void fapx_options_init(fapx_options *o);
/* &o->port (for bindings that see fapx_options without its port member). */
fap_port_options *fapx_options_port(fapx_options *o);

/* Open the port at path and start the node. *out is set only on success.
 * Errors: -EINVAL (bad mode/id/depth), -ENOMEM, or fap_port_open's error. */
int  fapx_open(fapx **out, const char *path, const fapx_options *o);
/* Stop the engine, close the port, free everything. NULL accepted.
 * Threads blocked in fapx_rx_wait / fapx_event_wait / fapx_tx_wait /
 * fapx_flush return -ESHUTDOWN before it frees the handle. Bounded
 * whatever the line does: a write still waiting for room FAPX_STOP_GRACE_MS
 * after the stop request is abandoned, so close returns within ~0.1 s
 * (documented bound 0.5 s); what was dropped is counted in tx_abandoned. */
void fapx_close(fapx *h);
/* fapx_close, and the final counters (tx_abandoned included) into *out
 * (may be NULL). */
void fapx_close_stats(fapx *h, fapx_stats *out);
/* How long a stop lets a write in progress finish before abandoning it. */
#define FAPX_STOP_GRACE_MS 100

/* Master only (-EPERM on a slave). A new slave starts inactive and is
 * queried at the end of the current data cycle. */
int  fapx_add_slave(fapx *h, unsigned id);
int  fapx_remove_slave(fapx *h, unsigned id);
/* 1 active, 0 inactive, -ENOENT not listed, -EINVAL, -EPERM on a slave. */
int  fapx_slave_active(fapx *h, unsigned id);
/* Bit i set: slave i listed / active (master; 0 on a slave). */
uint32_t fapx_listed_mask(fapx *h);
uint32_t fapx_active_mask(fapx *h);

/* Queue len (1..1024) bytes for dst (master: 1..31; slave: 0..31 but not
 * its own ID). Sent in this node's next turn. -EAGAIN when the tx queue is
 * full. */
int  fapx_tx(fapx *h, unsigned dst, const void *data, size_t len);
/* The same, waiting up to timeout_ms (< 0: forever) for room in the tx
 * queue instead of returning -EAGAIN; -ETIMEDOUT if none came. */
int  fapx_tx_wait(fapx *h, unsigned dst, const void *data, size_t len, int timeout_ms);
/* Wait until every queued frame has been transmitted (timeout_ms < 0:
 * forever). 0, -ETIMEDOUT, -ESHUTDOWN. */
int  fapx_flush(fapx *h, int timeout_ms);
/* Take the oldest received DATA frame addressed to this node: copies it to
 * buf, sets *src (may be NULL), returns its length. -EAGAIN if none. */
int  fapx_rx(fapx *h, void *buf, size_t cap, unsigned *src);
/* The same, waiting up to timeout_ms (< 0: forever) for a frame. */
int  fapx_rx_wait(fapx *h, void *buf, size_t cap, unsigned *src, int timeout_ms);
/* Events: 0 and *ev filled, or -EAGAIN / -ETIMEDOUT. */
int  fapx_event_get(fapx *h, fapx_event *ev);
int  fapx_event_wait(fapx *h, fapx_event *ev, int timeout_ms);
/* A file descriptor that polls readable exactly while a received frame or
 * an event is queued (level-triggered: it stays readable until fapx_rx and
 * fapx_event_get have emptied both queues; never read() it yourself). For
 * select/poll/epoll or asyncio's loop.add_reader. Owned by the handle. */
int  fapx_notify_fd(fapx *h);
/* Install (or with NULL remove) the engine-thread callback. */
void fapx_set_callback(fapx *h, fapx_callback cb, void *ctx);
/* Install (or with NULL remove) the wire trace hook (fap_trace.h): called
 * on the engine thread with every frame sent and every frame (or rejected
 * candidate) received. When this returns, the previous hook is not
 * running and will not be called again. Not from inside the hook. */
void fapx_set_trace(fapx *h, fap_trace_fn fn, void *ctx);

void fapx_get_stats(fapx *h, fapx_stats *out);
/* Queue fill levels right now. */
unsigned fapx_rx_pending(fapx *h);
unsigned fapx_tx_pending(fapx *h);
/* The port layer underneath (for fap_port_mode etc.); valid until close. */
fap_port *fapx_port(fapx *h);
const char *fapx_strerror(int err);
const char *fapx_event_name(int type);

/* ---- the classic API's default handle (<fap.h>) ---- */
/* Options the next fapInit/fapConfig use (NULL = the vendor defaults):
 * port options and queue depths are taken by fapInit, timing (idc_us when
 * fapConfig's idcTime is 0, id_answer_us, data_done_us, send_budget_us,
 * gap_us, reopen_us) by fapConfig. mode/id are ignored: fapConfig sets them. */
void fapClassicSetOptions(const fapx_options *o);
/* The default handle once fapConfig has started it, else NULL. */
fapx *fapClassicHandle(void);
/* Stop and free the default handle; afterwards fapInit may be called again
 * and every other classic call returns E_INIT. */
void fapClassicClose(void);

#ifdef __cplusplus
}
#endif
#endif /* FAPX_H */
