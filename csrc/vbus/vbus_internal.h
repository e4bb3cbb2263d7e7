/* vbus_internal.h - the virtual bus's state and the calls its files share:
 * vbus.c (the public API: open, close, fault controls, stats), vbus_ports.c
 * (each port's output queue, who has it open, disconnect and reconnect),
 * vbus_relay.c (the relay thread: poll loop, timer, wire model sink) and
 * vbus_links.c (the link directory, and links removed at exit). The wire
 * model itself is vbus_wire.c (sans-I/O), captures vbus_capture.c.
 *
 * Locking: one mutex guards everything; the relay holds it except while in
 * poll(). Control calls take it briefly; disconnect waits for the relay to
 * have closed the pty (fds are only ever closed by the relay thread, never
 * under a poll() in progress). Not installed. */
#ifndef LF_VBUS_INTERNAL_H
#define LF_VBUS_INTERNAL_H

#include <pthread.h>
#include <stdint.h>
#include <sys/types.h>

#include "common/mono_clock.h"
#include "fap_vbus.h"
#include "vbus/vbus_capture.h"
#include "vbus/vbus_pty.h"
#include "vbus/vbus_wire.h"

/* Bytes queued for a node that does not keep up; beyond that, drop and
 * count (stats.overflow) rather than stall the whole bus. */
#define LF_VBUS_OUTQ_CAP (64 * 1024)
#define LF_VBUS_READ_CHUNK (64 * 1024)
#define LF_VBUS_MAX_BAUD 10000000u
#define LF_VBUS_RECONNECT_RETRY_NS (100 * LF_NS_PER_MS)

typedef struct vbus_port {
    lf_pty pty;               /* fds are -1 while disconnected */
    char *link;               /* the stable path handed to users */
    uint8_t *outq;            /* ring of LF_VBUS_OUTQ_CAP bytes for this node */
    size_t oq_head, oq_len;
    int attached;             /* nodes that have the slave open (inotify) */
    lf_ns reconnect_at;       /* LF_NEVER while connected */
    int disconnect_req;       /* a control call asked for a disconnect... */
    unsigned disconnect_ms;   /* ...of this long */
} vbus_port;

struct fap_vbus {
    unsigned n_ports;
    char *dir;
    int own_dir;              /* we created dir: remove it at close */
    vbus_port port[FAP_VBUS_MAX_PORTS];
    lf_wire wire;
    lf_capture cap;
    int evfd, tfd;
    int infd;                 /* inotify: nodes opening/closing the slaves */
    int tracking;             /* attach tracking works (else: all attached) */
    lf_ns timer_armed;        /* LF_NEVER = disarmed */
    uint8_t *rbuf;

    pthread_t thread;
    int thread_started;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    int closing;
    uint64_t req_gen, done_gen;
    fap_port_rt rt;           /* real-time option: the relay applies it, open waits */
    int rt_err, rt_known;

    uint64_t bytes_out, overflow, disconnects;

    pid_t owner;              /* the process that opened it (not a fork child) */
    struct fap_vbus *live_next;
};

/* ---- vbus_ports.c (mutex held; disconnect/reconnect: relay thread only) */

/* Send n bytes to a port's node: written now, or queued while the node
 * does not keep up (beyond LF_VBUS_OUTQ_CAP: dropped, stats.overflow). */
void lf_vbus_port_write(fap_vbus *b, vbus_port *pt, const uint8_t *d, size_t n);
/* Write as much of the queue as the pty takes. */
void lf_vbus_outq_flush(fap_vbus *b, vbus_port *pt);
/* Read the inotify events: who opened or closed which port. */
void lf_vbus_attach_events(fap_vbus *b);
/* Start watching a new pty (before its path is published). */
void lf_vbus_port_watch(fap_vbus *b, vbus_port *pt);
void lf_vbus_port_disconnect(fap_vbus *b, unsigned i, unsigned ms, lf_ns now);
void lf_vbus_port_reconnect(fap_vbus *b, unsigned i, lf_ns now);

/* ---- vbus_relay.c */

/* The relay thread (arg: the bus). */
void *lf_vbus_relay_main(void *arg);
/* The wire model's sink: deliveries to the ports, events to the capture. */
lf_wire_sink lf_vbus_sink(fap_vbus *b);
/* Wake the relay (a control call or close changed something). */
void lf_vbus_wake(fap_vbus *b);

/* ---- vbus_links.c */

/* b->dir: link_dir (created if missing), or a fresh temporary directory.
 * 0 or -errno. */
int lf_vbus_make_dir(fap_vbus *b, const char *link_dir);
/* Unlink the port links, and the directory if we created it. */
void lf_vbus_remove_links(fap_vbus *b);
/* Buses whose links an exit without fap_vbus_close removes. */
void lf_vbus_live_add(fap_vbus *b);
void lf_vbus_live_remove(fap_vbus *b);

#endif
