/* port_backend.h - the seam between the port logic (port.c) and the OS.
 *
 * port.c never calls open/ioctl/read/... directly: it goes through one of
 * these tables. lf_port_posix_backend is the real one; tests pass a fake
 * that wraps a pty and answers the RS-485 / modem-line ioctls a pty refuses,
 * recording what it was asked to do. Every function returns what its libc
 * namesake returns and sets errno the same way. ctx is the backend's own.
 */
#ifndef LF_PORT_BACKEND_H
#define LF_PORT_BACKEND_H

#include <poll.h>
#include <stdint.h>
#include <sys/types.h>
#include <termios.h>

#include "fap_port.h"

typedef struct lf_port_backend {
    int (*open)(void *ctx, const char *path, int flags);
    int (*close)(void *ctx, int fd);
    /* request is one of TIOCEXCL, TIOCNXCL, TIOCGRS485, TIOCSRS485,
     * TIOCMBIS, TIOCMBIC, TIOCSERGETLSR; arg as for ioctl(2) (NULL for
     * EXCL/NXCL). */
    int (*ioctl)(void *ctx, int fd, unsigned long request, void *arg);
    int (*tcgetattr)(void *ctx, int fd, struct termios *t);
    int (*tcsetattr)(void *ctx, int fd, int action, const struct termios *t);
    int (*tcflush)(void *ctx, int fd, int queue);
    int (*tcdrain)(void *ctx, int fd);
    int (*flock)(void *ctx, int fd, int op);
    ssize_t (*read)(void *ctx, int fd, void *buf, size_t n);
    ssize_t (*write)(void *ctx, int fd, const void *buf, size_t n);
    int (*poll)(void *ctx, struct pollfd *fds, nfds_t n, int timeout_ms);
    /* Sleep until an absolute CLOCK_MONOTONIC time in ns (RTS delays and
     * turnaround); a fake may record the call instead of sleeping. */
    void (*sleep_until)(void *ctx, int64_t deadline_ns);
    /* Optional: free ctx when the port is freed (a backend that owns its
     * ctx, port_net.c); NULL = the caller owns it. */
    void (*destroy)(void *ctx);
    /* Optional: the clock rx pacing measures the link's pace with
     * (CLOCK_MONOTONIC ns); NULL = lf_now_ns. A fake wire runs its own. */
    int64_t (*now)(void *ctx);
    /* FAP_RS485_GPIO: request line of the gpiochip device chip as an
     * output at value (0/1): the line's fd, or a negative errno; set it:
     * 0 or a negative errno. The line fd is closed with close(). NULL in
     * a backend without GPIO: that mode then fails with -EOPNOTSUPP. */
    int (*gpio_open)(void *ctx, const char *chip, unsigned line, int value);
    int (*gpio_set)(void *ctx, int line_fd, int value);
    /* Where sysfs is (USB latency_timer); NULL = "/sys". Tests point it
     * at a fake tree. */
    const char *sysfs_root;
    /* Optional: told, before the open, where the port keeps its cancel fd
     * pointer (fap_port.cancel_fd: NULL = none, else readable = stop), so a
     * backend whose open waits (port_net.c: name lookup, connect, RFC 2217
     * negotiation) ends those waits too. */
    void (*attach)(void *ctx, const int *const *cancel_fd);
    /* What the transport can do: FAP_PORT_CAP_* (fap_port_caps). A fake
     * that leaves it 0 is neither paced nor a network link. */
    unsigned caps;
    /* Optional: what a reply timeout must allow on top of the wire time for
     * the link's round trip, in ns (lf_port_link_slack_ns); NULL = 0. */
    int64_t (*slack_ns)(void *ctx);
    /* Optional: the connection's last set-up note into buf (fap_port_warning:
     * n bytes, always terminated), returning its length; NULL = none. */
    size_t (*warning)(void *ctx, char *buf, size_t n);
} lf_port_backend;

extern const lf_port_backend lf_port_posix_backend;
/* Its poll and sleep_until, shared by backends whose fd is an ordinary one
 * (port_net.c: a socket). */
int lf_port_posix_poll(void *ctx, struct pollfd *fds, nfds_t n, int timeout_ms);
void lf_port_posix_sleep_until(void *ctx, int64_t deadline_ns);

/* termios speed <-> baud (port_config.c), for backends that read a
 * struct termios (port_net.c's tcsetattr). */
int lf_port_baud_to_speed(unsigned baud, speed_t *out);
unsigned lf_port_speed_to_baud(speed_t speed);   /* 0 if not in the table */

/* The posix backend's GPIO functions (port_gpio.c, uAPI v2 ioctls). */
int lf_port_gpio_open(void *ctx, const char *chip, unsigned line, int value);
int lf_port_gpio_set(void *ctx, int line_fd, int value);

/* fap_port_open with an explicit backend (tests). be must outlive the port;
 * ctx is passed back to every backend call. */
int lf_port_open_with_backend(fap_port **out, const char *path,
                              const fap_port_options *o,
                              const lf_port_backend *be, void *ctx);
/* The same, whose open already watches *cancel_fd (NULL: none). */
int lf_port_open_backend_cancel(fap_port **out, const char *path, const fap_port_options *o,
                                const lf_port_backend *be, void *ctx, const int *cancel_fd);
/* fap_port_open (device or URL) whose open already watches *cancel_fd
 * (NULL: none): port_transport.c, the one place that maps a port string to
 * its transport and calls both sides. */
int lf_port_open_cancel(fap_port **out, const char *path, const fap_port_options *o,
                        const int *cancel_fd);

#endif
