/* fap_port.h - libfap serial port layer: termios raw 8N1, RS-485 direction
 * control, echo suppression, turnaround delay, deadline reads.
 *
 * Every protocol engine in libfap (FAP, exec async, mikroC) talks to the
 * wire only through this API. Codecs and state machines never include it.
 *
 * Return convention: 0 or a byte count on success, a negative errno on
 * failure (-ENOTTY, -EBUSY, -EIO, -ENXIO, -ETIMEDOUT ...), plus the libfap
 * specific negative codes below. fap_port_strerror() names any of them.
 */
#ifndef FAP_PORT_H
#define FAP_PORT_H

#include <stddef.h>
#include <stdint.h>
#include <sys/types.h>

#ifdef __cplusplus
extern "C" {
#endif

/* libfap specific error codes (negative, outside the errno range). */
#define FAP_PORT_ECOLLISION  (-10001)  /* echo read back differs from what was sent */
#define FAP_PORT_ECLOSED     (-10002)  /* port closed (by fap_port_close/shutdown)  */
/* Network transports (tcp://, rfc2217://; docs/port.md "Network transports"). */
#define FAP_PORT_EURL        (-10010)  /* bad URL: unknown scheme, no host, bad port or query */
#define FAP_PORT_ENET485     (-10011)  /* kernel or soft-RTS direction asked on a URL */
#define FAP_PORT_ERESOLVE    (-10012)  /* the URL's host name does not resolve */
#define FAP_PORT_EREFUSED    (-10013)  /* the RFC 2217 server refused COM-PORT-OPTION,
                                          the baud rate or 8N1 */

/* Real-time settings of an engine's I/O thread (docs/realtime.md).
 * fap_port_open checks them (a throwaway thread tries them; mlockall is
 * process-wide and stays) and fails with one of these codes when the
 * process may not have them; each engine's I/O thread then applies them to
 * itself (fap_port_rt_enter). Never silently ignored. */
#define FAP_PORT_ERTPRIV     (-10020)  /* SCHED_FIFO/RR refused: no CAP_SYS_NICE and
                                          RLIMIT_RTPRIO below the priority */
#define FAP_PORT_ERTCPU      (-10021)  /* an asked CPU is not in the process's allowed set */
#define FAP_PORT_EMLOCK      (-10022)  /* mlockall refused: RLIMIT_MEMLOCK, no CAP_IPC_LOCK,
                                          or not enough memory */

typedef enum fap_rt_policy {
    FAP_RT_OFF = 0,    /* the thread keeps its policy (default) */
    FAP_RT_FIFO = 1,   /* SCHED_FIFO at priority */
    FAP_RT_RR = 2      /* SCHED_RR at priority */
} fap_rt_policy;

#define FAP_RT_MAX_CPUS 64   /* CPUs an affinity mask can name (0..63) */

typedef struct fap_port_rt {
    fap_rt_policy policy;   /* default FAP_RT_OFF */
    int priority;           /* 1..99 with FIFO/RR (sched_get_priority_min/max), else 0 */
    int mlock;              /* 1: mlockall(MCL_CURRENT | MCL_FUTURE) at open */
    uint64_t cpus;          /* affinity: bit i = CPU i; 0 = leave the thread's */
} fap_port_rt;

/* How the transmitter is switched on and off. */
typedef enum fap_rs485_mode {
    FAP_RS485_AUTO = 0,     /* try KERNEL, fall back to NONE; see fap_port_mode() */
    FAP_RS485_KERNEL = 1,   /* TIOCSRS485 with SER_RS485_ENABLED, kernel toggles RTS */
    FAP_RS485_SOFT_RTS = 2, /* assert RTS, write, tcdrain(), release RTS */
    FAP_RS485_NONE = 3,     /* auto-direction transceiver, USB adapter, pty */
    FAP_RS485_GPIO = 4      /* a GPIO line (gpio_chip, gpio_line) is the DE/RE
                               pin: asserted, write, tcdrain(), released */
} fap_rs485_mode;

/* "Not given": keep what the device's own RS-485 config (TIOCGRS485: the
 * device tree, an earlier program) says. The defaults of
 * fap_port_options_init; see docs/port.md. */
#define FAP_PORT_KEEP        (-1)   /* rts_active_high, rx_during_tx */
#define FAP_PORT_KEEP_DELAY  (~0u)  /* delay_before_send_us, delay_after_send_us */

typedef struct fap_port_options {
    unsigned baud;                 /* any standard termios rate; default 115200 */
    fap_rs485_mode rs485_mode;     /* default FAP_RS485_AUTO */
    int rts_active_high;           /* RTS (GPIO mode: DE) pin level while sending, in every mode:
                                      1 high, 0 low, FAP_PORT_KEEP (default) the
                                      device's config, else high */
    unsigned delay_before_send_us; /* RTS to the sending level -> first bit (kernel:
                                      ms, rounded up); FAP_PORT_KEEP_DELAY (default)
                                      the device's config, else 0 */
    unsigned delay_after_send_us;  /* last bit -> RTS back (same rules) */
    int rx_during_tx;              /* kernel mode: SER_RS485_RX_DURING_TX, 0/1, or
                                      FAP_PORT_KEEP (default): the device's */
    int echo_suppression;          /* read back and drop our own bytes (2-wire adapters) */
    unsigned echo_timeout_us;      /* how long to wait for the echo; 0 = 20 char times + 20 ms */
    unsigned turnaround_us;        /* minimum quiet time after the last received byte
                                      before this node transmits (0 = none) */
    int exclusive;                 /* TIOCEXCL + flock(LOCK_EX|LOCK_NB); default 1 */
    unsigned write_timeout_us;     /* longest one fap_port_write may take to hand all
                                      bytes to the driver (-ETIMEDOUT after);
                                      0 = twice the frame's wire time + 1 s */
    /* Added after write_timeout_us (appended: the fields above keep their
     * offsets). FAP_RS485_GPIO: the GPIO character device and line offset
     * of the DE/RE pin; its level while sending is rts_active_high (KEEP =
     * high), its delays delay_before/after_send_us (KEEP = 0), as for soft
     * RTS. The path is copied at open. Default NULL / 0. */
    const char *gpio_chip;         /* e.g. "/dev/gpiochip0" */
    unsigned gpio_line;            /* line offset on that chip */
    int low_latency;               /* a USB adapter's latency_timer (FTDI, sysfs)
                                      at 1 ms while open, the old value back at
                                      close: 1 always, 0 never, FAP_PORT_KEEP
                                      (default) in soft-RTS and GPIO modes */
    /* Appended: real-time settings of the engine's I/O thread (see
     * fap_port_rt below, docs/realtime.md). Default: all off. */
    fap_port_rt rt;
} fap_port_options;

typedef struct fap_port_stats {
    uint64_t tx_bytes;
    uint64_t rx_bytes;
    uint64_t echo_bytes;      /* echo bytes read back and dropped */
    uint64_t collisions;      /* echo mismatches */
    uint64_t write_errors;
    uint64_t read_errors;
    uint64_t reopens;
    uint64_t rt_refused;      /* appended: an I/O thread's real-time settings refused
                                 after the open's check passed (fap_port_rt_enter) */
} fap_port_stats;

typedef struct fap_port fap_port;   /* opaque; one per open device */

/* Fill *o with the defaults documented above. */
void fap_port_options_init(fap_port_options *o);

/* Open and configure a device. *out is set only on success.
 * Errors: -errno of open/ioctl/tcsetattr; -EBUSY if another process holds
 * it; -EINVAL for an unsupported baud rate; an explicit KERNEL or SOFT_RTS
 * mode that the device refuses fails with that ioctl's errno (-ENOTTY on a
 * pty) and nothing stays open. GPIO mode: -EINVAL without gpio_chip, else
 * the errno of opening the chip or requesting the line (-ENOENT, -EBUSY
 * when another consumer holds the line). */
int fap_port_open(fap_port **out, const char *path, const fap_port_options *o);

/* Close the port (restores the RS-485 config the port had before, if we
 * changed it: kernel mode, and soft-RTS mode on a device whose kernel
 * RS-485 was on). NULL is accepted. */
void fap_port_close(fap_port *p);

/* Close and open the same path again with the same options (after a USB
 * unplug, say). Returns 0 or a negative error; on error the port stays
 * usable for further reopen attempts. */
int fap_port_reopen(fap_port *p);

/* The mode actually in force (never FAP_RS485_AUTO once open). */
fap_rs485_mode fap_port_mode(const fap_port *p);
const char *fap_rs485_mode_name(fap_rs485_mode m);

/* The file descriptor, for poll(); -1 while the device is gone. */
int fap_port_fd(const fap_port *p);
const char *fap_port_path(const fap_port *p);
unsigned fap_port_baud(const fap_port *p);

/* What a port string names, as fap_port_open reads it (docs/port.md,
 * "What a port string is"): FAP_PORT_KIND_DEVICE for a path without "://"
 * (a tty, a pty), FAP_PORT_KIND_TCP / FAP_PORT_KIND_RFC2217 for a URL that
 * parses, FAP_PORT_KIND_OTHER for a URL of a scheme libfap does not open
 * (pyserial's socket://, loop://), FAP_PORT_KIND_INVALID for NULL or a
 * tcp:// / rfc2217:// URL that does not parse. Sans-I/O: no name lookup, no
 * stat. fap_port_open refuses OTHER and INVALID with FAP_PORT_EURL. */
#define FAP_PORT_KIND_DEVICE   0
#define FAP_PORT_KIND_TCP      1
#define FAP_PORT_KIND_RFC2217  2
#define FAP_PORT_KIND_OTHER    (-1)
#define FAP_PORT_KIND_INVALID  (-2)
int fap_port_kind(const char *path);

/* What an open port's transport can do (FAP_PORT_CAP_* bits; 0 for NULL):
 * the transport's, not the settings in force (fap_port_mode says which
 * direction mode an open settled on). A device has kernel RS-485, RTS,
 * the lock and is paced; a network transport is only NETWORK. */
#define FAP_PORT_CAP_RS485    0x01u  /* kernel RS-485 (TIOCSRS485) can be asked */
#define FAP_PORT_CAP_RTS      0x02u  /* the port can drive a direction line (soft RTS, GPIO) */
#define FAP_PORT_CAP_LOCK     0x04u  /* an exclusive lock holds the line (flock, TIOCEXCL) */
#define FAP_PORT_CAP_PACED    0x08u  /* bytes come at the line's baud: wire times predict replies */
#define FAP_PORT_CAP_NETWORK  0x10u  /* a network link: a round trip (rtt_ms) on top of the wire */
unsigned fap_port_caps(const fap_port *p);

/* Network transports: the last note of the connection's set-up (an RFC
 * 2217 server that did not answer a setting: the open went on), copied
 * into buf (n bytes, always terminated). Returns its length, 0 when there
 * is none or p is a device. */
size_t fap_port_warning(const fap_port *p, char *buf, size_t n);

/* Write all n bytes: waits out the turnaround delay, switches direction per
 * the mode, handles EINTR and partial writes, drains with tcdrain(), reads
 * back the echo when suppression is on. Returns n, or a negative error:
 * -EIO/-ENXIO/-ENODEV device vanished, FAP_PORT_ECOLLISION echo mismatch. */
ssize_t fap_port_write(fap_port *p, const void *buf, size_t n);

/* Read up to n bytes, waiting until at least one byte arrives or the
 * absolute CLOCK_MONOTONIC deadline (ns, see fap_port_now_ns) passes.
 * deadline 0 = do not wait; INT64_MAX = wait forever.
 * Returns the byte count, 0 at the deadline, or a negative error
 * (-EIO/-ENXIO when the device vanished, -EINTR never). */
ssize_t fap_port_read(fap_port *p, void *buf, size_t n, int64_t deadline_ns);

/* Discard unread input (and untransmitted output). */
int fap_port_flush(fap_port *p);

/* Drop input received and not yet read, by reading it (at most 64 reads of
 * 256 bytes): unlike fap_port_flush, output still queued for the wire is
 * kept (a broadcast sent just before). 0, or a negative error. */
int fap_port_discard_input(fap_port *p);

/* fap_port_write without waiting for the last byte to leave the UART
 * where nothing depends on it: tcdrain() only with soft RTS (released
 * after the last bit) or echo suppression (its deadline counts from the
 * drain). For a reply or a broadcast nobody times; same returns. */
ssize_t fap_port_send(fap_port *p, const void *buf, size_t n);

/* One request/reply round in one call (for protocol masters): drop the
 * input received and not read yet (by reading it; queued output is kept),
 * write all n bytes like fap_port_write, then read like fap_port_read
 * (up to cap bytes, the first chunk, waiting until deadline_ns; cap 0 =
 * no reply awaited: returns 0 after the write). Unlike fap_port_write it
 * calls tcdrain() only when something depends on it (soft RTS, echo
 * suppression): the caller's deadline must include the request's wire
 * time. Returns the reply bytes read, 0 at the deadline, or a negative
 * error (of the discard, the write or the read). */
ssize_t fap_port_transact(fap_port *p, const void *req, size_t n, void *reply, size_t cap,
                          int64_t deadline_ns);

/* CLOCK_MONOTONIC now, in ns: the clock the deadlines above use. */
int64_t fap_port_now_ns(void);

void fap_port_get_stats(const fap_port *p, fap_port_stats *out);
const char *fap_port_strerror(int err);

/* Why FAP_RS485_AUTO settled on NONE: the errno (positive) the kernel
 * RS-485 ioctl failed with, e.g. ENOTTY on a pty; 0 if AUTO got KERNEL or
 * the mode was explicit. */
int fap_port_auto_errno(const fap_port *p);

/* Kernel mode: the RS-485 config the driver accepted, read back with
 * TIOCGRS485 after setting it; it may differ from the request (drivers
 * clamp delays, drop flags they lack). Fills whichever
 * pointers are not NULL (flags are SER_RS485_* bits, delays in ms) and
 * returns 0, or -ENOTTY when the port is not in FAP_RS485_KERNEL mode. */
int fap_port_kernel_rs485(const fap_port *p, uint32_t *flags,
                          uint32_t *delay_before_ms, uint32_t *delay_after_ms);

/* The baud rates fap_port_open accepts, ascending: the i-th one, or 0
 * past the end. Tools list them when a rate is refused. */
unsigned fap_port_baud_rate(size_t i);

/* What a device is set to now, without changing it (for port listings).
 * First, without opening it: if another process holds the port (the
 * flock fap_port_open takes, as /proc/locks lists it, or a UUCP lock file
 * /var/lock/LCK..name with a live pid), returns -EBUSY and never opens
 * it (an open would raise RTS under that program). Otherwise opens path
 * briefly (non-exclusive, O_NONBLOCK; the usual tty open side effect of
 * raising DTR/RTS applies), reads termios and TIOCGRS485, writes
 * the same RS-485 config back with TIOCSRS485 (a no-op where it works),
 * closes. Fills *baud (0 if not a standard rate) and, when the driver
 * answers TIOCGRS485, the RS-485 flags and delays. Returns 0 if the
 * kernel can switch RS-485 mode on this port, 1 if the driver reports an
 * RS-485 config but refuses to set one (a plain 16550), -ENOTTY if the
 * driver has no RS-485 (pty, most USB adapters), -EBUSY (held, see
 * above), or the -errno of stat, reading /proc/locks, open or tcgetattr.
 * NULL pointers are skipped. */
int fap_port_probe(const char *path, unsigned *baud, uint32_t *rs485_flags,
                   uint32_t *delay_before_ms, uint32_t *delay_after_ms);

/* The direction settings in force, in any mode, after "not given" was
 * resolved: RTS pin level while sending (1 high, 0 low) and the delays
 * in us (kernel mode: what the driver accepted). NULL pointers are
 * skipped. Returns 0, or -EINVAL for a NULL port. */
int fap_port_rts_settings(const fap_port *p, int *active_high,
                          unsigned *delay_before_us, unsigned *delay_after_us);

/* fap_port_open whose waits (room to write when the line does not drain,
 * the echo, a read's deadline) also end once *cancel_fd turns readable: the
 * call in progress and every later one that waits return -ECANCELED. The
 * caller owns cancel_fd (an eventfd, say) and keeps it (and the int) alive
 * while the port is open; writing to it from another thread is how a close
 * ends a blocked call at once. -EINVAL for a NULL cancel_fd. */
int fap_port_open_cancellable(fap_port **out, const char *path, const fap_port_options *o,
                              const int *cancel_fd);

/* Self-verifying direction control, on a line whose transceiver echoes
 * (RX during TX). Each of `rounds` rounds drops pending input, writes the
 * n-byte pattern with fap_port_write (soft RTS / GPIO: it returns after the
 * line was released; other modes after tcdrain) while a second thread
 * reads the echo until timeout_ms; the round's margin is the write's return
 * minus the moment the last echoed byte was read (CLOCK_MONOTONIC ns):
 * negative = the port let go before its last byte came back (tcdrain does
 * not cover the adapter). The read side's own latency (FIFO timeout, USB
 * polling) is in the margin. Needs echo_suppression off. Returns 0, or
 * -EINVAL (NULL, n 0, rounds > FAP_PORT_CHECK_MAX_ROUNDS, echo
 * suppression on), or the first error of the discard or the write. */
#define FAP_PORT_CHECK_MAX_ROUNDS 16
typedef struct fap_port_check {
    unsigned rounds;              /* rounds run */
    unsigned echoed;              /* rounds whose whole pattern came back */
    uint64_t collisions;          /* echoed bytes that differ from those sent */
    int64_t margin_ns[FAP_PORT_CHECK_MAX_ROUNDS];   /* per echoed round */
} fap_port_check;
int fap_port_check_direction(fap_port *p, const void *pattern, size_t n, unsigned rounds,
                             unsigned timeout_ms, fap_port_check *out);

/* Parse a real-time spec: comma-separated items, any order, each once:
 * "fifo:PRIO" or "rr:PRIO" (1..99), "mlock", "cpu=N" or "cpu=N-M" (CPUs
 * 0..63; items may repeat to add CPUs), "off" alone (or "" or NULL) for
 * none. Example: "fifo:50,mlock,cpu=1". Fills *out only on success.
 * Returns 0, or -EINVAL with a one-line reason naming the bad item in why
 * (n bytes, always terminated; NULL = none). */
int fap_port_rt_parse(const char *spec, fap_port_rt *out, char *why, size_t n);

/* The spec of the environment variable FAP_REALTIME (the classic API's
 * way in: fapInit reads it), parsed like fap_port_rt_parse; unset or empty
 * = all off. Returns 0 or -EINVAL (why as above). */
int fap_port_rt_from_env(fap_port_rt *out, char *why, size_t n);

/* Apply rt to the calling thread now: mlockall if asked, then the CPU
 * affinity, then the scheduling policy. NULL or all off: 0, nothing done.
 * Returns 0, -EINVAL (a value out of range), FAP_PORT_ERTCPU,
 * FAP_PORT_EMLOCK or FAP_PORT_ERTPRIV; the settings applied before a
 * failing one stay. */
int fap_port_rt_apply(const fap_port_rt *rt);

/* Try rt in a short-lived thread (the calling thread keeps its policy and
 * CPUs; mlockall, process-wide, stays in force). fap_port_open calls it.
 * Same returns as fap_port_rt_apply, or the -errno of pthread_create. */
int fap_port_rt_check(const fap_port_rt *rt);

/* Apply the port's real-time settings (opened with, checked by the open)
 * to the calling thread, once per thread and port: later calls from the
 * same thread cost a compare. Engines call it where their I/O thread
 * starts (the FAP engine thread, the exec async and mikroC calls that
 * read and write, the virtual bus relay). Returns 0 or fap_port_rt_apply's
 * code; a refusal is also counted in fap_port_stats.rt_refused. */
int fap_port_rt_enter(fap_port *p);
/* 1 when err, a code a fap_port_* call (or an engine on a port) returned,
 * says the device is gone and only fap_port_reopen can bring it back:
 * -EIO, -ENXIO, -ENODEV (unplugged, a pty whose other end closed; a
 * network transport's dropped connection is -EIO), -EPIPE, -EBADF (the
 * stream or fd closed under the call) and FAP_PORT_ECLOSED; else 0. The
 * one list: the port layer, the FAP engine and fap_py all ask here. */
int fap_port_error_is_gone(int err);

#ifdef __cplusplus
}
#endif
#endif /* FAP_PORT_H */
