/* port_posix.c - the real OS table under the device transport: thin
 * wrappers around libc, nothing else (the logic lives in port_device.c). */
#include "port/port_device.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include "common/mono_clock.h"

static int px_open(void *ctx, const char *path, int flags)
{
    (void)ctx;
    return open(path, flags);
}

static int px_close(void *ctx, int fd)
{
    (void)ctx;
    return close(fd);
}

static int px_ioctl(void *ctx, int fd, unsigned long request, void *arg)
{
    (void)ctx;
    return ioctl(fd, request, arg);
}

static int px_tcgetattr(void *ctx, int fd, struct termios *t)
{
    (void)ctx;
    return tcgetattr(fd, t);
}

static int px_tcsetattr(void *ctx, int fd, int action, const struct termios *t)
{
    (void)ctx;
    return tcsetattr(fd, action, t);
}

static int px_tcflush(void *ctx, int fd, int queue)
{
    (void)ctx;
    return tcflush(fd, queue);
}

static int px_tcdrain(void *ctx, int fd)
{
    (void)ctx;
    return tcdrain(fd);
}

static int px_flock(void *ctx, int fd, int op)
{
    (void)ctx;
    return flock(fd, op);
}

static ssize_t px_read(void *ctx, int fd, void *buf, size_t n)
{
    (void)ctx;
    return read(fd, buf, n);
}

static ssize_t px_write(void *ctx, int fd, const void *buf, size_t n)
{
    (void)ctx;
    return write(fd, buf, n);
}

int lf_port_posix_poll(void *ctx, struct pollfd *fds, nfds_t n, int timeout_ms)
{
    (void)ctx;
    return poll(fds, n, timeout_ms);
}

void lf_port_posix_sleep_until(void *ctx, int64_t deadline_ns)
{
    (void)ctx;
    lf_sleep_until(deadline_ns);
}

const lf_port_os lf_port_posix_os = {
    .open = px_open,
    .close = px_close,
    .ioctl = px_ioctl,
    .tcgetattr = px_tcgetattr,
    .tcsetattr = px_tcsetattr,
    .tcflush = px_tcflush,
    .tcdrain = px_tcdrain,
    .flock = px_flock,
    .read = px_read,
    .write = px_write,
    .poll = lf_port_posix_poll,
    .sleep_until = lf_port_posix_sleep_until,
    .gpio_open = lf_port_gpio_open,   /* port_gpio.c */
    .gpio_set = lf_port_gpio_set,
    .caps = FAP_PORT_CAP_RS485 | FAP_PORT_CAP_RTS | FAP_PORT_CAP_LOCK | FAP_PORT_CAP_PACED,
};
