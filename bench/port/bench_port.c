/* bench_port - request/response latency and bulk throughput through the
 * port layer on an (unpaced) pty pair, against raw syscalls and libmodbus
 * RTU in the same run, and against the wire time at 115200 baud.
 *
 * The far end (a thread on the pty master) answers every 8-byte request
 * (a Modbus "read 1 holding register" frame) with the 7-byte response, so
 * every contender does the same exchange. Run: bench_port [iterations]. */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <pty.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "fap_port.h"

#ifdef HAVE_LIBMODBUS
#include <modbus.h>
#endif

#define REQ_LEN 8
#define RSP_LEN 7

static int64_t now_ns(void) { return fap_port_now_ns(); }

static uint16_t crc_modbus(const uint8_t *p, size_t n)
{
    uint16_t crc = 0xFFFF;
    for (size_t i = 0; i < n; i++) {
        crc ^= p[i];
        for (int b = 0; b < 8; b++)
            crc = (crc & 1) ? (uint16_t)((crc >> 1) ^ 0xA001) : (uint16_t)(crc >> 1);
    }
    return crc;
}

static void frame_crc(uint8_t *f, size_t n_without_crc)
{
    uint16_t c = crc_modbus(f, n_without_crc);
    f[n_without_crc] = (uint8_t)(c & 0xFF);
    f[n_without_crc + 1] = (uint8_t)(c >> 8);
}

/* ---- the far end ---------------------------------------------------------- */

typedef struct far_end {
    int master;
    int echo;              /* send our request back first (2-wire adapter) */
    atomic_int stop;
    long answered;
} far_end;

static int read_exact(int fd, uint8_t *b, size_t n, atomic_int *stop)
{
    size_t got = 0;
    while (got < n) {
        ssize_t r = read(fd, b + got, n - got);
        if (r > 0) {
            got += (size_t)r;
            continue;
        }
        if (r < 0 && errno != EAGAIN && errno != EINTR)
            return -1;
        if (stop && atomic_load(stop))
            return -1;
        struct pollfd pf = {.fd = fd, .events = POLLIN};
        poll(&pf, 1, 50);
    }
    return 0;
}

static int write_all(int fd, const uint8_t *b, size_t n)
{
    size_t off = 0;
    while (off < n) {
        ssize_t w = write(fd, b + off, n - off);
        if (w > 0) {
            off += (size_t)w;
            continue;
        }
        if (w < 0 && errno != EAGAIN && errno != EINTR)
            return -1;
        struct pollfd pf = {.fd = fd, .events = POLLOUT};
        poll(&pf, 1, 50);
    }
    return 0;
}

static void *far_end_thread(void *arg)
{
    far_end *f = arg;
    uint8_t rsp[RSP_LEN] = {0x01, 0x03, 0x02, 0x00, 0x2A};
    frame_crc(rsp, RSP_LEN - 2);
    uint8_t out[REQ_LEN + RSP_LEN];
    while (!atomic_load(&f->stop)) {
        uint8_t req[REQ_LEN];
        if (read_exact(f->master, req, REQ_LEN, &f->stop) < 0)
            break;
        size_t n = 0;
        if (f->echo) {
            memcpy(out, req, REQ_LEN);
            n = REQ_LEN;
        }
        memcpy(out + n, rsp, RSP_LEN);
        n += RSP_LEN;
        if (write_all(f->master, out, n) < 0)
            break;
        f->answered++;
    }
    return NULL;
}

/* ---- contenders ------------------------------------------------------------ */

static uint8_t g_req[REQ_LEN] = {0x01, 0x03, 0x00, 0x00, 0x00, 0x01};

typedef struct contender {
    const char *name;
    int echo;                                  /* far end echoes */
    void *(*setup)(const char *path, int echo);
    int (*exchange)(void *ctx);                /* 0 ok */
    void (*teardown)(void *ctx);
} contender;

/* raw syscalls: the floor */
typedef struct raw_ctx { int fd; } raw_ctx;

static void *raw_setup(const char *path, int echo)
{
    (void)echo;
    raw_ctx *c = calloc(1, sizeof *c);
    c->fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    struct termios t;
    tcgetattr(c->fd, &t);
    cfmakeraw(&t);
    t.c_cc[VMIN] = 1;
    t.c_cc[VTIME] = 0;
    tcsetattr(c->fd, TCSANOW, &t);
    tcflush(c->fd, TCIOFLUSH);
    return c;
}

static int raw_exchange(void *ctx)
{
    raw_ctx *c = ctx;
    uint8_t rsp[RSP_LEN];
    if (write_all(c->fd, g_req, REQ_LEN) < 0)
        return -1;
    return read_exact(c->fd, rsp, RSP_LEN, NULL);
}

static void raw_teardown(void *ctx)
{
    raw_ctx *c = ctx;
    close(c->fd);
    free(c);
}

/* libfap port layer */
static void *fap_setup(const char *path, int echo)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.echo_suppression = echo;
    fap_port *p = NULL;
    int err = fap_port_open(&p, path, &o);
    if (err) {
        fprintf(stderr, "fap_port_open: %s\n", fap_port_strerror(err));
        return NULL;
    }
    return p;
}

static int fap_exchange(void *ctx)
{
    fap_port *p = ctx;
    if (fap_port_write(p, g_req, REQ_LEN) != REQ_LEN)
        return -1;
    uint8_t rsp[RSP_LEN];
    size_t got = 0;
    int64_t deadline = fap_port_now_ns() + 1000000000LL;
    while (got < RSP_LEN) {
        ssize_t r = fap_port_read(p, rsp + got, RSP_LEN - got, deadline);
        if (r <= 0)
            return -1;
        got += (size_t)r;
    }
    return 0;
}

static void fap_teardown(void *ctx) { fap_port_close(ctx); }

#ifdef HAVE_LIBMODBUS
static void *mb_setup(const char *path, int echo)
{
    (void)echo;
    modbus_t *m = modbus_new_rtu(path, 115200, 'N', 8, 1);
    if (!m)
        return NULL;
    modbus_set_slave(m, 1);
    modbus_set_response_timeout(m, 1, 0);
    if (modbus_connect(m) < 0) {
        modbus_free(m);
        return NULL;
    }
    return m;
}

static int mb_exchange(void *ctx)
{
    uint16_t reg;
    return modbus_read_registers(ctx, 0, 1, &reg) == 1 ? 0 : -1;
}

static void mb_teardown(void *ctx)
{
    modbus_close(ctx);
    modbus_free(ctx);
}
#endif

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

static void run(const contender *c, int iters)
{
    int master, slave;
    char name[128];
    if (openpty(&master, &slave, name, NULL, NULL) < 0) {
        perror("openpty");
        return;
    }
    struct termios t;
    tcgetattr(slave, &t);
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    close(slave);
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    void *ctx = c->setup(name, c->echo);   /* before the far end: a master
                                              with no slave open reads EIO */
    far_end f = {.master = master, .echo = c->echo};
    pthread_t th;
    pthread_create(&th, NULL, far_end_thread, &f);
    int64_t *lat = calloc((size_t)iters, sizeof *lat);
    int ok = 0;
    int64_t t0 = now_ns();
    for (int i = 0; ctx && i < iters; i++) {
        int64_t a = now_ns();
        if (c->exchange(ctx) == 0)
            lat[ok++] = now_ns() - a;
    }
    int64_t total = now_ns() - t0;
    if (ctx)
        c->teardown(ctx);
    atomic_store(&f.stop, 1);
    pthread_join(th, NULL);
    close(master);
    if (ok == 0) {
        printf("%-28s %8s\n", c->name, "failed");
        free(lat);
        return;
    }
    qsort(lat, (size_t)ok, sizeof *lat, cmp_i64);
    printf("%-28s %8d %10.1f %10.1f %10.1f %12.0f\n", c->name, ok,
           lat[ok / 2] / 1e3, lat[(size_t)ok * 99 / 100] / 1e3, lat[ok - 1] / 1e3,
           ok / (total / 1e9));
    free(lat);
}

/* Bulk: one 64 KiB fap_port_write vs one raw write loop, drained by a thread. */
typedef struct drainer { int fd; size_t want; } drainer;

static void *drain_thread(void *arg)
{
    drainer *d = arg;
    uint8_t buf[8192];
    size_t got = 0;
    while (got < d->want) {
        ssize_t r = read(d->fd, buf, sizeof buf);
        if (r > 0) {
            got += (size_t)r;
            continue;
        }
        struct pollfd pf = {.fd = d->fd, .events = POLLIN};
        poll(&pf, 1, 100);
    }
    return NULL;
}

static void bulk(int use_fap, size_t total)
{
    int master, slave;
    char name[128];
    openpty(&master, &slave, name, NULL, NULL);
    close(slave);
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    uint8_t *buf = calloc(1, 65536);
    drainer d = {.fd = master, .want = total};
    void *ctx = use_fap ? fap_setup(name, 0) : raw_setup(name, 0);
    pthread_t th;
    pthread_create(&th, NULL, drain_thread, &d);
    int64_t t0 = now_ns();
    for (size_t off = 0; off < total; off += 65536) {
        if (use_fap)
            fap_port_write(ctx, buf, 65536);
        else
            write_all(((raw_ctx *)ctx)->fd, buf, 65536);
    }
    pthread_join(th, NULL);
    int64_t el = now_ns() - t0;
    if (use_fap)
        fap_teardown(ctx);
    else
        raw_teardown(ctx);
    close(master);
    free(buf);
    printf("%-28s %10.1f MB/s\n", use_fap ? "fap_port_write 64 KiB" : "raw write() 64 KiB",
           total / (el / 1e9) / 1e6);
}

int main(int argc, char **argv)
{
    int iters = argc > 1 ? atoi(argv[1]) : 5000;
    static const contender cs[] = {
        {"raw syscalls", 0, raw_setup, raw_exchange, raw_teardown},
        {"fap_port (none)", 0, fap_setup, fap_exchange, fap_teardown},
        {"fap_port (echo suppression)", 1, fap_setup, fap_exchange, fap_teardown},
#ifdef HAVE_LIBMODBUS
        {"libmodbus RTU", 0, mb_setup, mb_exchange, mb_teardown},
#endif
    };
    double wire_us = (REQ_LEN + RSP_LEN) * 10 * 1e6 / 115200.0;
    printf("request %d B / response %d B over an unpaced pty, %d exchanges each\n",
           REQ_LEN, RSP_LEN, iters);
    printf("wire time of one exchange at 115200 8N1: %.1f us (%.0f exchanges/s max)\n\n",
           wire_us, 1e6 / wire_us);
    printf("%-28s %8s %10s %10s %10s %12s\n", "contender", "ok", "p50 us", "p99 us",
           "max us", "exch/s");
    for (size_t i = 0; i < sizeof cs / sizeof cs[0]; i++)
        run(&cs[i], iters);
#ifndef HAVE_LIBMODBUS
    printf("(libmodbus not found at build time: apt-get install libmodbus-dev)\n");
#endif
    printf("\nbulk, 16 MiB through the pty:\n");
    bulk(0, 16u << 20);
    bulk(1, 16u << 20);
    printf("(115200 baud carries 0.0115 MB/s; 4 Mbaud 0.4 MB/s)\n");
    return 0;
}
