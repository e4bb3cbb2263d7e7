/* port_cancel.c - the posix backend with a cancel fd in every poll
 * (port_cancel.h). */
#include "port/port_cancel.h"

#include <errno.h>
#include <poll.h>
#include <string.h>

#include "port/port_backend.h"

#define PX lf_port_posix_backend
static int c_open(void *c, const char *p, int f) { (void)c; return PX.open(NULL, p, f); }
static int c_close(void *c, int fd) { (void)c; return PX.close(NULL, fd); }
static int c_ioctl(void *c, int fd, unsigned long r, void *a) { (void)c; return PX.ioctl(NULL, fd, r, a); }
static int c_tcgetattr(void *c, int fd, struct termios *t) { (void)c; return PX.tcgetattr(NULL, fd, t); }
static int c_tcsetattr(void *c, int fd, int a, const struct termios *t)
{
    (void)c;
    return PX.tcsetattr(NULL, fd, a, t);
}
static int c_tcflush(void *c, int fd, int q) { (void)c; return PX.tcflush(NULL, fd, q); }
static int c_tcdrain(void *c, int fd) { (void)c; return PX.tcdrain(NULL, fd); }
static int c_flock(void *c, int fd, int op) { (void)c; return PX.flock(NULL, fd, op); }
static ssize_t c_read(void *c, int fd, void *b, size_t n) { (void)c; return PX.read(NULL, fd, b, n); }
static ssize_t c_write(void *c, int fd, const void *b, size_t n) { (void)c; return PX.write(NULL, fd, b, n); }
static void c_sleep_until(void *c, int64_t t) { (void)c; PX.sleep_until(NULL, t); }

static int c_poll(void *ctx, struct pollfd *fds, nfds_t n, int timeout_ms)
{
    const int *cancel_fd = ctx;
    struct pollfd all[8];
    if (n >= sizeof all / sizeof all[0])     /* the port layer polls one fd */
        return PX.poll(NULL, fds, n, timeout_ms);
    memcpy(all, fds, n * sizeof *fds);
    all[n] = (struct pollfd){.fd = *cancel_fd, .events = POLLIN};
    int r = PX.poll(NULL, all, n + 1, timeout_ms);
    if (r > 0 && all[n].revents) {
        errno = ECANCELED;
        return -1;
    }
    for (nfds_t i = 0; i < n; i++)
        fds[i].revents = all[i].revents;
    return r;
}

static const lf_port_backend cancellable = {
    c_open, c_close, c_ioctl, c_tcgetattr, c_tcsetattr, c_tcflush, c_tcdrain,
    c_flock, c_read, c_write, c_poll, c_sleep_until,
};

int lf_port_open_cancellable(fap_port **out, const char *path, const fap_port_options *o,
                             const int *cancel_fd)
{
    if (!cancel_fd)
        return -EINVAL;
    return lf_port_open_with_backend(out, path, o, &cancellable, (void *)cancel_fd);
}

int fap_port_open_cancellable(fap_port **out, const char *path, const fap_port_options *o,
                              const int *cancel_fd)
{
    return lf_port_open_cancellable(out, path, o, cancel_fd);
}
