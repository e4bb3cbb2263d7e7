/* port_internal.h - the fap_port struct and the helpers shared by the
 * port layer's files (lifecycle port.c, device setup port_config.c, I/O
 * port_io.c). Not installed; nothing outside csrc/port includes it. */
#ifndef LF_PORT_INTERNAL_H
#define LF_PORT_INTERNAL_H

#include <errno.h>
#include <linux/serial.h>
#include <pthread.h>
#include <stdint.h>

#include "fap_port.h"
#include "port/port_backend.h"
#include "port/rx_plan.h"

/* One open device: everything port_config_open() sets up and
 * port_config_close() undoes. */
typedef struct lf_port_conn {
    int fd;                       /* -1 when none */
    fap_rs485_mode mode;          /* in force, never AUTO */
    int excl_set;                 /* locked exclusive: unlock on close */
    int rs485_restore;            /* we changed the RS-485 config */
    struct serial_rs485 rs485_saved;   /* rs485_get before we touched it */
    struct serial_rs485 rs485_active;  /* rs485_get after our rs485_set */
    int gpio_fd;                  /* GPIO mode: the DE line's fd, else -1 */
    int latency_saved;            /* USB latency_timer (ms) to restore, -1 none */
    char latency_file[160];       /* its sysfs file */
    int tio_restore;              /* soft RTS: restore_line at close */
    /* Resolved line settings (options, else the device's config). */
    int rts_active_high;          /* pin high while sending */
    unsigned delay_before_us, delay_after_us;
    int auto_errno;               /* AUTO fell back to NONE: rs485's errno */
} lf_port_conn;

struct fap_port {
    const lf_port_transport *be;  /* the line's transport (port_backend.h) */
    void *ctx;
    char *path;
    char *gpio_chip;              /* opt.gpio_chip points here (a copy) */
    fap_port_options opt;         /* validated copy, used again by reopen */

    /* Lock order: tx_mu, then rx_mu, then st_mu. */
    pthread_mutex_t tx_mu;        /* one writer at a time (frames never interleave) */
    pthread_mutex_t rx_mu;        /* around read(): the echo read-back holds it
                                     for a whole write so no reader steals echo */
    pthread_mutex_t st_mu;        /* the fields below */
    pthread_cond_t idle_cv;       /* busy dropped to 0 */

    /* What fap_port_fd() hands out: an epoll fd over the device fd and
     * pend_efd, so a poller wakes for device input AND for bytes parked in
     * pend (which the device fd alone would never signal). */
    int poll_fd;
    int pend_efd;                 /* eventfd: readable while pend_len > 0 */

    /* Input that was already queued when an echo-suppressed write began:
     * set aside (it is not our echo), returned first by fap_port_read.
     * Guarded by rx_mu. */
    uint8_t *pend;
    size_t pend_off, pend_len, pend_cap;

    lf_port_conn conn;
    int gone_err;                 /* <0: device vanished (or reopen failed) */
    int busy;                     /* read/write calls currently using conn.fd */
    int64_t last_rx_ns;           /* CLOCK_MONOTONIC of the last received byte */
    int rx_empty;                 /* the last read left nothing queued (atomic;
                                     port_io.c: poll before the next read) */
    fap_port_stats stats;
    const int *cancel_fd;         /* readable: every wait ends with -ECANCELED
                                     (lf_port_open_cancellable); NULL: none */
    uint64_t rt_serial;           /* port_rt.c: which open a thread applied rt for */
    int intr_fd;                  /* the port's own cancel fd (an eventfd,
                                     lf_port_open_interruptible), else -1 */
    int interrupted;              /* atomic: lf_port_interrupt was called */
    lf_rx_link rx_link;           /* rx_pacing.c: frames came at the baud's pace */
    int64_t tx_end_ns;            /* port_io.c: when the last frame written can have
                                     left (write start + its wire time); atomic */
};

/* port_config.c */
/* Open p->path per p->opt into *c. On error nothing stays open and the
 * negative errno is returned. */
int lf_port_conn_open(const fap_port *p, lf_port_conn *c);
/* Undo lf_port_conn_open (restore the line and RS-485, unlock, close). */
void lf_port_conn_close(const fap_port *p, lf_port_conn *c);
/* Soft RTS / GPIO: drive the RTS pin (GPIO mode: the DE line) to c's
 * sending (1) or receive (0) level. */
int lf_port_rts(const fap_port *p, int fd, const lf_port_conn *c, int sending);

/* port_latency.c: set a USB adapter's latency_timer to 1 ms while open
 * (per p->opt.low_latency and c->mode), and put the old value back. */
void lf_port_latency_low(const fap_port *p, lf_port_conn *c);
void lf_port_latency_restore(lf_port_conn *c);

/* port_probe.c: does another process hold path (a lock on its inode in
 * locks_file, /proc/locks' format; or a live UUCP LCK..name in uucp_dir,
 * NULL = skip)? 1 yes, 0 no, negative errno (stat, reading locks_file). */
int lf_port_held_elsewhere(const char *path, const char *locks_file, const char *uucp_dir);
/* Open a sysfs/proc/lock file to read: O_NONBLOCK, and only a regular
 * file (a FIFO would block, /dev/zero never ends): the fd, or -1 with
 * errno (EINVAL: not a regular file). */
int lf_open_regular(const char *path);

/* port.c: I/O calls borrow the fd; a vanished device is closed by the
 * last borrower, so an fd number is never reused under a running call. */
int lf_port_acquire(fap_port *p, int *fd, fap_rs485_mode *mode);
void lf_port_release(fap_port *p);
/* Add/remove a device fd to/from poll_fd. */
void lf_port_watch(fap_port *p, int fd);
void lf_port_unwatch(fap_port *p, int fd);
/* Mark pend non-empty / empty on pend_efd (rx_mu held). */
void lf_port_pend_signal(fap_port *p, int nonempty);
/* An I/O call failed with err (negative): if that says the device
 * vanished, record it, so later calls fail fast until a reopen. */
void lf_port_note_error(fap_port *p, int err);

/* port_rt.c: check p->opt.rt at open (fap_port_rt_check) and number the
 * open for fap_port_rt_enter; the name of its error codes (else NULL). */
int lf_port_rt_open(fap_port *p);
const char *lf_port_rt_strerror(int err);

#endif
