/* pty_util.h - pty pairs and deadline-bounded master-side I/O for the port
 * tests. The test plays the far end of the wire on the master fd. */
#ifndef PORT_TEST_PTY_UTIL_H
#define PORT_TEST_PTY_UTIL_H

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

/* unit.h's REQUIRE evaluates its argument twice (once in CHECK, once in
 * the if): with a call inside, the call runs twice. MUST evaluates once. */
#define MUST(cond) do { int must_ok_ = !!(cond); \
    CHECK(must_ok_ && #cond); if (!must_ok_) return; } while (0)

typedef struct test_pty {
    int master;
    char name[128];   /* slave path, what fap_port_open gets */
} test_pty;

static inline int64_t tp_now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

/* Open a pty pair; only the master stays open here (the port opens the
 * slave by name). Returns 0 or -errno. */
static inline int tp_open(test_pty *t)
{
    int slave = -1;
    if (openpty(&t->master, &slave, t->name, NULL, NULL) < 0)
        return -errno;
    close(slave);
    fcntl(t->master, F_SETFL, fcntl(t->master, F_GETFL) | O_NONBLOCK);
    fcntl(t->master, F_SETFD, FD_CLOEXEC);
    return 0;
}

static inline void tp_close(test_pty *t)
{
    if (t->master >= 0)
        close(t->master);
    t->master = -1;
}

/* Read exactly n bytes from fd within timeout_ms; returns bytes read. */
static inline size_t tp_read_exact(int fd, void *buf, size_t n, int timeout_ms)
{
    int64_t deadline = tp_now_ns() + (int64_t)timeout_ms * 1000000LL;
    size_t got = 0;
    while (got < n) {
        ssize_t r = read(fd, (char *)buf + got, n - got);
        if (r > 0) {
            got += (size_t)r;
            continue;
        }
        if (r < 0 && errno != EAGAIN && errno != EINTR)
            break;
        int64_t left = deadline - tp_now_ns();
        if (left <= 0)
            break;
        struct pollfd pf = {.fd = fd, .events = POLLIN};
        poll(&pf, 1, (int)(left / 1000000LL) + 1);
    }
    return got;
}

/* Write all n bytes to fd within timeout_ms; returns bytes written. */
static inline size_t tp_write_all(int fd, const void *buf, size_t n, int timeout_ms)
{
    int64_t deadline = tp_now_ns() + (int64_t)timeout_ms * 1000000LL;
    size_t off = 0;
    while (off < n) {
        ssize_t w = write(fd, (const char *)buf + off, n - off);
        if (w > 0) {
            off += (size_t)w;
            continue;
        }
        if (w < 0 && errno != EAGAIN && errno != EINTR)
            break;
        int64_t left = deadline - tp_now_ns();
        if (left <= 0)
            break;
        struct pollfd pf = {.fd = fd, .events = POLLOUT};
        poll(&pf, 1, (int)(left / 1000000LL) + 1);
    }
    return off;
}

/* Number of open fds of this process (to prove a failed open leaks none). */
static inline int tp_count_fds(void)
{
    DIR *d = opendir("/proc/self/fd");
    if (!d)
        return -1;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL)
        if (e->d_name[0] != '.')
            n++;
    closedir(d);
    return n - 1;   /* the DIR's own fd */
}

#endif
