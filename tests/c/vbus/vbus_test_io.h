/* vbus_test_io.h - what a node does with a bus port in the vbus tests:
 * open the symlink raw, write all, read exactly n bytes before a deadline.
 * Plain open()+termios so these tests do not depend on the port layer. */
#ifndef VBUS_TEST_IO_H
#define VBUS_TEST_IO_H

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stddef.h>
#include <stdint.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

static inline long long vt_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (long long)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

/* Open a bus port like a serial device: raw, non-blocking, stale input flushed. */
static inline int vt_open(const char *path)
{
    int fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return -errno;
    struct termios t;
    if (tcgetattr(fd, &t) == 0) {
        cfmakeraw(&t);
        tcsetattr(fd, TCSANOW, &t);
    }
    tcflush(fd, TCIOFLUSH);
    return fd;
}

static inline int vt_write_all(int fd, const void *buf, size_t n)
{
    const uint8_t *p = buf;
    while (n) {
        ssize_t w = write(fd, p, n);
        if (w < 0) {
            if (errno == EAGAIN || errno == EINTR) {
                struct pollfd pfd = { .fd = fd, .events = POLLOUT };
                poll(&pfd, 1, 100);
                continue;
            }
            return -errno;
        }
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

/* Read until n bytes arrived or timeout_ms passed; returns the count read,
 * or -errno if the read failed before anything arrived. */
static inline ssize_t vt_read_n(int fd, void *buf, size_t n, int timeout_ms)
{
    uint8_t *p = buf;
    size_t got = 0;
    long long deadline = vt_now_ms() + timeout_ms;
    while (got < n) {
        long long left = deadline - vt_now_ms();
        if (left <= 0)
            break;
        struct pollfd pfd = { .fd = fd, .events = POLLIN };
        if (poll(&pfd, 1, (int)left) <= 0)
            continue;
        ssize_t r = read(fd, p + got, n - got);
        if (r > 0) {
            got += (size_t)r;
        } else if (r < 0 && errno != EAGAIN && errno != EINTR) {
            return got ? (ssize_t)got : -errno;
        } else if (r == 0) {
            return got ? (ssize_t)got : -EIO;   /* hung up */
        }
    }
    return (ssize_t)got;
}

/* Bytes already waiting on fd, without blocking. */
static inline int vt_pending(int fd)
{
    struct pollfd pfd = { .fd = fd, .events = POLLIN };
    return poll(&pfd, 1, 0) > 0 && (pfd.revents & POLLIN);
}
#endif
