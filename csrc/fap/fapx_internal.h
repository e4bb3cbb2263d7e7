/* The handle behind fapx.h and the classic API: queues shared by the
 * application threads and the engine thread (all under `lock`), plus the
 * engine's private state (decoder, state machine). */
#ifndef LF_FAPX_INTERNAL_H
#define LF_FAPX_INTERNAL_H
#include <pthread.h>
#include <stdint.h>
#include "fapx.h"
#include "fap_port.h"
#include "fap/codec.h"
#include "fap/sm_master.h"
#include "fap/sm_slave.h"
#include "fap/ring.h"
#include "common/trace.h"

typedef struct lf_fapx_item {    /* a queued DATA frame (rx: src; tx: dst) */
    uint8_t  peer;
    uint16_t len;
    uint8_t  data[LF_FAP_MAX_DATA];
} lf_fapx_item;

/* Counters only the engine thread writes (published into fapx.stats). */
typedef struct lf_engine_counts {
    uint64_t frames_tx, bytes_tx, write_errors, collisions;
    uint64_t port_lost, port_reopened, rx_dropped;
    uint64_t ev_dropped;          /* events lost to a full event queue */
    uint64_t tx_abandoned;        /* frames a stop dropped (fapx_stats.tx_abandoned) */
} lf_engine_counts;

struct fapx {
    pthread_mutex_t lock;
    pthread_cond_t cond;          /* rx/event arrival, tx drained, close (CLOCK_MONOTONIC) */
    fap_port *port;
    fapx_options o;

    /* ---- shared, under lock ---- */
    int mode;                     /* -1 until started */
    unsigned id;
    int started, stop, closing;
    int exited;                   /* the engine thread has left its loop */
    int tx_abandoned_now;         /* the last stop dropped output: flush fails */
    unsigned waiters;             /* threads inside a *_wait call */
    lf_ring rx, tx, ev;
    int tx_inflight;              /* a popped frame is being transmitted */
    int tx_kick;                  /* fapx_tx queued something for the engine */
    uint32_t want_listed;         /* the application's slave list */
    uint8_t add_epoch[32];        /* bumped by each add (re-add = fresh slave) */
    uint32_t active_pub;          /* engine-published active mask */
    int notify_set;               /* notify_fd currently readable */
    fapx_callback cb;
    void *cb_ctx;
    lf_trace trace;               /* wire trace hook (own lock, see trace.h) */
    fapx_stats stats;             /* published snapshot */

    /* ---- fds ---- */
    int wake_fd;                  /* eventfd: application -> engine */
    int notify_fd;                /* eventfd: readable while rx/ev pending */
    int timer_fd;                 /* timerfd, CLOCK_MONOTONIC absolute */
    int epoll_fd;                 /* the engine waits here (wake, timer, port) */
    int hold_epoll_fd;            /* ... or here while a frame is held (wake, timer) */
    int cancel_fd;                /* eventfd: readable = abandon the write in
                                     progress (stop grace period over) */
    int port_cancel;              /* the fd the port watches (it keeps &port_cancel):
                                     o.cancel_fd during the open, then cancel_fd */
    pthread_t thread;

    /* ---- engine thread only ---- */
    lf_fap_decoder dec;
    lf_fap_master m;
    lf_fap_slave s;
    uint32_t applied_listed;
    uint8_t applied_epoch[32];
    int port_down;
    lf_ns reopen_at;
    lf_ns armed;                  /* timerfd deadline currently armed */
    int no_pwait2;                /* epoll_pwait2 missing (kernel < 5.11): the timerfd */
    lf_engine_counts ec;
};

/* epoll tags of the engine's fds */
enum { LF_FAPX_TAG_WAKE = 1, LF_FAPX_TAG_TIMER = 2, LF_FAPX_TAG_PORT = 3 };

/* Zero timing/depth fields take their defaults. */
void lf_fapx_fill_defaults(fapx_options *o);
/* Create: allocate, open the port (no thread yet). 0 or negative errno. */
int  lf_fapx_create(fapx **out, const char *path, const fapx_options *o);
/* Start the engine as mode/id with o's timing. 0 or negative errno. */
int  lf_fapx_start(fapx *h, unsigned mode, unsigned id);
/* Stop the engine thread (queues are kept). */
void lf_fapx_stop(fapx *h);
/* Stop, wake waiters, close the port, free. */
void lf_fapx_destroy(fapx *h);
/* The same, copying the final counters to *final first (NULL: not). */
void lf_fapx_destroy_stats(fapx *h, fapx_stats *final);
/* Engine thread body (engine.c). */
void *lf_fapx_engine_main(void *arg);
/* Wake the engine (eventfd). */
void lf_fapx_wake(fapx *h);
/* Whether a stop was requested (the engine between frames of a turn). */
int lf_fapx_stopping(fapx *h);
#endif
