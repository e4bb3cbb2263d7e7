/* port_backend.h - the seam between the port logic and a transport: a
 * table of line-level operations, as pyserial's and libmodbus's backends
 * put it.
 *
 * The port logic (port.c lifecycle, port_config.c bring-up, port_io.c I/O)
 * never calls open/ioctl/termios: it asks the transport to set the line to
 * a baud (8N1 raw is all this library uses), flush, drain, switch RS-485 or
 * the RTS pin, lock the line, and read/write/poll its fd. Two transports:
 *
 *   - the device transport (port_device.c): a tty; termios and the tty
 *     ioctls live there and nowhere else. It runs over an OS table
 *     (lf_port_os, port_device.h): the real one (port_posix.c) or a test's
 *     fake that wraps a pty;
 *   - the network transport (port_net.c): tcp:// and rfc2217://, whose
 *     set_line is the RFC 2217 line settings (raw TCP: the server's own).
 *
 * A new transport is one file that fills this table and one row in the
 * transport map (port_transport.c). An optional operation left NULL means
 * "this transport cannot": the port logic then answers as a device without
 * that feature would (rs485: -ENOTTY, so AUTO settles on NONE; lock: no
 * lock needed; tx_empty: the drain is all there is). Engines ask what a
 * transport can do with fap_port_caps, never by looking at this table.
 *
 * Unless said otherwise an operation returns 0 or a negative errno; read,
 * write and poll return what their libc namesakes return and set errno the
 * same way. ctx is the transport's own. A port has at most one connection
 * open at a time (a reopen closes the old one first).
 */
#ifndef LF_PORT_BACKEND_H
#define LF_PORT_BACKEND_H

#include <linux/serial.h>   /* struct serial_rs485: the RS-485 config, a kernel type */
#include <poll.h>
#include <stdint.h>
#include <sys/types.h>

#include "fap_port.h"

/* flush's queue */
enum { LF_PORT_FLUSH_IN = 1, LF_PORT_FLUSH_OUT = 2, LF_PORT_FLUSH_BOTH = 3 };

typedef struct lf_port_transport {
    /* Open the line path names (a device path; a URL's transport has
     * parsed it into ctx already): its fd, or a negative errno. */
    int (*open)(void *ctx, const char *path);
    /* Close fd (the line's, or the GPIO line's fd from gpio_open). */
    int (*close)(void *ctx, int fd);
    /* Raw 8N1 at baud, no flow control, reads non-blocking. hold_rts (soft
     * RTS): the close must not move RTS, and restore_line puts back what
     * the line had before (the transport keeps it). */
    int (*set_line)(void *ctx, int fd, unsigned baud, int hold_rts);
    /* Optional: undo a set_line(hold_rts) at close without moving RTS;
     * baud is the one in force. NULL: nothing to put back. */
    void (*restore_line)(void *ctx, int fd, unsigned baud);
    /* Drop queued bytes: LF_PORT_FLUSH_IN, _OUT or _BOTH. */
    int (*flush)(void *ctx, int fd, int queue);
    /* Return once what was written has left (as far as the transport can
     * tell). */
    int (*drain)(void *ctx, int fd);
    /* Optional: the line's kernel RS-485 config, read / set. */
    int (*rs485_get)(void *ctx, int fd, struct serial_rs485 *r);
    int (*rs485_set)(void *ctx, int fd, const struct serial_rs485 *r);
    /* Optional: drive the RTS pin high (1) or low (0). */
    int (*rts)(void *ctx, int fd, int pin_high);
    /* Optional: lock the line, exclusive (1: nobody else may open it) or
     * shared (0: shares with other shared openers): -EBUSY if held. */
    int (*lock)(void *ctx, int fd, int exclusive);
    /* Optional: undo an exclusive lock's hold on later opens before the
     * close (which drops the rest). */
    void (*unlock)(void *ctx, int fd);
    /* Optional: is the transmitter empty (the last stop bit out)? 1 yes,
     * 0 no, negative: cannot tell on this line. */
    int (*tx_empty)(void *ctx, int fd);
    ssize_t (*read)(void *ctx, int fd, void *buf, size_t n);
    ssize_t (*write)(void *ctx, int fd, const void *buf, size_t n);
    int (*poll)(void *ctx, struct pollfd *fds, nfds_t n, int timeout_ms);
    /* Sleep until an absolute CLOCK_MONOTONIC time in ns (RTS delays and
     * turnaround); a fake may record the call instead of sleeping. */
    void (*sleep_until)(void *ctx, int64_t deadline_ns);
    /* Optional: free ctx when the port is freed (a transport that owns its
     * ctx); NULL = the caller owns it. */
    void (*destroy)(void *ctx);
    /* Optional: the clock rx pacing measures the link's pace with
     * (CLOCK_MONOTONIC ns); NULL = lf_now_ns. A fake wire runs its own. */
    int64_t (*now)(void *ctx);
    /* FAP_RS485_GPIO: request line of the gpiochip device chip as an
     * output at value (0/1): the line's fd, or a negative errno; set it:
     * 0 or a negative errno. The line fd is closed with close(). NULL in
     * a transport without GPIO: that mode then fails with -EOPNOTSUPP. */
    int (*gpio_open)(void *ctx, const char *chip, unsigned line, int value);
    int (*gpio_set)(void *ctx, int line_fd, int value);
    /* Where sysfs is (USB latency_timer); NULL = "/sys". Tests point it
     * at a fake tree. */
    const char *sysfs_root;
    /* Optional: told, before the open, where the port keeps its cancel fd
     * pointer (fap_port.cancel_fd: NULL = none, else readable = stop), so a
     * transport whose open waits (port_net.c: name lookup, connect, RFC 2217
     * negotiation) ends those waits too. */
    void (*attach)(void *ctx, const int *const *cancel_fd);
    /* What the transport can do: FAP_PORT_CAP_* (fap_port_caps). */
    unsigned caps;
    /* Optional: what a reply timeout must allow on top of the wire time for
     * the link's round trip, in ns (lf_port_link_slack_ns); NULL = 0. */
    int64_t (*slack_ns)(void *ctx);
    /* Optional: the connection's last set-up note into buf (fap_port_warning:
     * n bytes, always terminated), returning its length; NULL = none. */
    size_t (*warning)(void *ctx, char *buf, size_t n);
} lf_port_transport;

/* poll and sleep_until for a transport whose fd is an ordinary one
 * (port_posix.c; port_net.c: a socket). */
int lf_port_posix_poll(void *ctx, struct pollfd *fds, nfds_t n, int timeout_ms);
void lf_port_posix_sleep_until(void *ctx, int64_t deadline_ns);

/* Is baud one the port layer accepts (fap_port_baud_rate's table)? */
int lf_port_baud_ok(unsigned baud);

/* Open a port over transport tr with context ctx (port.c). tr must outlive
 * the port; ctx is passed back to every call, and freed by tr->destroy
 * (also when the open fails). The open watches *cancel_fd (NULL: none). */
int lf_port_open_transport(fap_port **out, const char *path, const fap_port_options *o,
                           const lf_port_transport *tr, void *ctx, const int *cancel_fd);
/* fap_port_open (device or URL) whose open already watches *cancel_fd
 * (NULL: none): port_transport.c, the one place that maps a port string to
 * its transport and calls both sides. */
int lf_port_open_cancel(fap_port **out, const char *path, const fap_port_options *o,
                        const int *cancel_fd);

#endif
