/* port_latency.c - a USB adapter's receive latency timer while the port is
 * open. FTDI chips hold received bytes up to latency_timer ms (16 by
 * default) before sending a partial USB packet: a reply's last bytes, and
 * the echo that tells a soft-RTS master the line is free, arrive late. The
 * ftdi_sio driver exposes the timer in sysfs; the port sets it to 1 ms
 * while open and writes the old value back at close. Best effort: no
 * such file (not an FTDI), or no permission, leaves things as they were. */
#include "port/port_internal.h"

#include <fcntl.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* <root>/class/tty/<name>/device/latency_timer for the device at path
 * (symlinks such as /dev/serial/by-id/... resolved). 0 or -1. */
static int latency_file(const fap_port *p, char *out, size_t cap)
{
    char real[PATH_MAX];
    if (!realpath(p->path, real))
        return -1;
    const char *name = strrchr(real, '/');
    name = name ? name + 1 : real;
    const char *root = p->be->sysfs_root ? p->be->sysfs_root : "/sys";
    int n = snprintf(out, cap, "%s/class/tty/%s/device/latency_timer", root, name);
    return n > 0 && (size_t)n < cap ? 0 : -1;
}

static int read_ms(const char *file)
{
    int fd = lf_open_regular(file);   /* never a FIFO or /dev/zero (a fake tree) */
    if (fd < 0)
        return -1;
    char buf[16] = {0};
    ssize_t n = read(fd, buf, sizeof buf - 1);
    close(fd);
    if (n <= 0)
        return -1;
    char *end;
    long v = strtol(buf, &end, 10);
    return end != buf && v >= 0 && v <= 255 ? (int)v : -1;
}

static int write_ms(const char *file, int ms)
{
    int fd = open(file, O_WRONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
    if (fd < 0)
        return -1;
    char buf[8];
    int n = snprintf(buf, sizeof buf, "%d\n", ms);
    int ok = write(fd, buf, (size_t)n) == n;
    close(fd);
    return ok ? 0 : -1;
}

void lf_port_latency_low(const fap_port *p, lf_port_conn *c)
{
    c->latency_saved = -1;
    int want = p->opt.low_latency;
    if (want == FAP_PORT_KEEP)   /* default: where we time the direction line */
        want = c->mode == FAP_RS485_SOFT_RTS || c->mode == FAP_RS485_GPIO;
    if (!want || latency_file(p, c->latency_file, sizeof c->latency_file) < 0)
        return;
    int old = read_ms(c->latency_file);
    if (old <= 1)
        return;   /* not an FTDI, or already as low: only ever lowered */
    if (write_ms(c->latency_file, 1) == 0)
        c->latency_saved = old;
}

void lf_port_latency_restore(lf_port_conn *c)
{
    if (c->latency_saved >= 0)
        (void)write_ms(c->latency_file, c->latency_saved);
    c->latency_saved = -1;
}
