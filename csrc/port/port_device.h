/* port_device.h - the device transport (a tty, port_device.c) and the OS
 * table it runs over.
 *
 * The device transport is the only place that builds a struct termios or
 * issues a tty ioctl; it does so through an lf_port_os, never directly:
 * lf_port_posix_os is the real one (port_posix.c: libc, nothing else);
 * tests pass a fake that wraps a pty and answers the RS-485 / modem-line
 * ioctls a pty refuses, recording what it was asked to do, so they run the
 * real device logic. Every function returns what its libc namesake returns
 * and sets errno the same way. ctx is the OS table's own.
 */
#ifndef LF_PORT_DEVICE_H
#define LF_PORT_DEVICE_H

#include <poll.h>
#include <stdint.h>
#include <sys/types.h>
#include <termios.h>

#include "fap_port.h"
#include "port/port_backend.h"

typedef struct lf_port_os {
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
    void (*sleep_until)(void *ctx, int64_t deadline_ns);
    /* Optional (as in lf_port_transport): the clock, GPIO, sysfs root. */
    int64_t (*now)(void *ctx);
    int (*gpio_open)(void *ctx, const char *chip, unsigned line, int value);
    int (*gpio_set)(void *ctx, int line_fd, int value);
    const char *sysfs_root;
    /* The transport's caps (fap_port_caps). A fake that leaves it 0 is
     * neither paced nor a network link. */
    unsigned caps;
} lf_port_os;

extern const lf_port_os lf_port_posix_os;

/* A device transport over os (os_ctx passed back to every os call): *tr and
 * *ctx for lf_port_open_transport, which owns *ctx from then on (freed by
 * tr->destroy). 0 or -ENOMEM. os must outlive the port. */
int lf_port_device_new(const lf_port_os *os, void *os_ctx, const lf_port_transport **tr,
                       void **ctx);

/* fap_port_open of a device path over an explicit OS table (tests): the
 * device transport over (os, ctx). */
int lf_port_open_with_backend(fap_port **out, const char *path, const fap_port_options *o,
                              const lf_port_os *os, void *ctx);

/* termios speed <-> baud (port_baud.c), for code that reads a struct
 * termios (port_device.c, port_probe.c). */
int lf_port_baud_to_speed(unsigned baud, speed_t *out);
unsigned lf_port_speed_to_baud(speed_t speed);   /* 0 if not in the table */

/* The posix OS table's GPIO functions (port_gpio.c, uAPI v2 ioctls). */
int lf_port_gpio_open(void *ctx, const char *chip, unsigned line, int value);
int lf_port_gpio_set(void *ctx, int line_fd, int value);

#endif
