/* port_probe.c - read a device's current line and RS-485 configuration
 * without changing it (for `fap ports` and similar listings).
 *
 * Every open of a tty raises DTR/RTS (O_NONBLOCK too; TIOCEXCL does not stop
 * root). On a port another program drives with soft RTS, active low, that
 * is its transmit level, held until its next write. So the probe first
 * looks, without opening, whether someone holds the port: the lock
 * fap_port_open takes (flock on the device node, seen in /proc/locks) or a
 * UUCP lock file (minicom, picocom: /var/lock/LCK..name with a live pid). */
#include "port/port_internal.h"
#include "port/port_device.h"

#include <fcntl.h>
#include <limits.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <termios.h>
#include <unistd.h>

/* Is there a lock on st's inode in a /proc/locks-format file? 1 yes, 0 no,
 * negative errno if the file cannot be read. Lines look like
 * "1: FLOCK  ADVISORY  WRITE 1234 00:05:123 0 EOF" (major:minor in hex,
 * inode in decimal; "->" marks a waiter, which holds nothing). */
int lf_open_regular(const char *path)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
    if (fd < 0)
        return -1;
    struct stat st;
    if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode)) {
        close(fd);
        errno = EINVAL;   /* a FIFO, /dev/zero ...: not a file to read */
        return -1;
    }
    return fd;
}

/* /proc/locks lists one line per lock: far fewer than this on any machine. */
#define LOCKS_MAX_LINES 1000000

static int locks_file_has(const char *locks, const struct stat *st)
{
    int fd = lf_open_regular(locks);
    FILE *f = fd >= 0 ? fdopen(fd, "r") : NULL;
    if (!f) {
        int err = errno;
        if (fd >= 0)
            close(fd);
        return -err;
    }
    char line[256];
    int held = 0;
    for (long lines = 0; !held && lines < LOCKS_MAX_LINES && fgets(line, sizeof line, f); lines++) {
        unsigned maj, min;
        unsigned long long ino;
        char kind[16];
        if (strstr(line, "->"))
            continue;
        if (sscanf(line, "%*d: %15s %*s %*s %*d %x:%x:%llu", kind, &maj, &min, &ino) != 4)
            continue;
        held = maj == major(st->st_dev) && min == minor(st->st_dev) &&
               ino == (unsigned long long)st->st_ino;
    }
    fclose(f);
    return held;
}

/* A UUCP lock file "LCK..<basename>" in dir whose pid (ASCII or a binary
 * int, both exist) is alive: 1, else 0. */
static int uucp_lock_held(const char *dir, const char *real)
{
    const char *base = strrchr(real, '/');
    base = base ? base + 1 : real;
    char name[PATH_MAX];
    if (snprintf(name, sizeof name, "%s/LCK..%s", dir, base) >= (int)sizeof name)
        return 0;
    int fd = lf_open_regular(name);
    if (fd < 0)
        return 0;
    char buf[32] = {0};
    ssize_t n = read(fd, buf, sizeof buf - 1);
    close(fd);
    long pid = 0;
    if (n == (ssize_t)sizeof(int)) {
        int bin;
        memcpy(&bin, buf, sizeof bin);
        pid = bin;
    } else if (n > 0) {
        pid = strtol(buf, NULL, 10);
    }
    if (pid <= 0 || pid > INT_MAX)
        return 0;
    return kill((pid_t)pid, 0) == 0 || errno == EPERM;
}

int lf_port_held_elsewhere(const char *path, const char *locks_file, const char *uucp_dir)
{
    struct stat st;
    if (stat(path, &st) < 0)
        return -errno;
    int held = locks_file_has(locks_file, &st);
    if (held != 0)
        return held;
    char real[PATH_MAX];
    if (uucp_dir && realpath(path, real))
        return uucp_lock_held(uucp_dir, real);
    return 0;
}

int fap_port_probe(const char *path, unsigned *baud, uint32_t *rs485_flags,
                   uint32_t *delay_before_ms, uint32_t *delay_after_ms)
{
    if (!path)
        return -EINVAL;
    /* Not ours to open: reported busy, untouched (a small race remains: a
     * program that locks between this look and the open below). */
    int held = lf_port_held_elsewhere(path, "/proc/locks", "/var/lock");
    if (held < 0)
        return held;
    if (held)
        return -EBUSY;
    int fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return -errno;
    int err = 0;
    struct termios t;
    if (tcgetattr(fd, &t) < 0) {
        err = -errno;
        goto out;
    }
    if (baud)
        *baud = lf_port_speed_to_baud(cfgetospeed(&t));
    struct serial_rs485 r;
    memset(&r, 0, sizeof r);
    if (ioctl(fd, TIOCGRS485, &r) < 0) {
        err = -errno;
        goto out;
    }
    if (rs485_flags)
        *rs485_flags = r.flags;
    if (delay_before_ms)
        *delay_before_ms = r.delay_rts_before_send;
    if (delay_after_ms)
        *delay_after_ms = r.delay_rts_after_send;
    /* Can the driver switch it? Writing back exactly what it reported changes
     * nothing; a plain 16550 (8250) answers TIOCGRS485 but refuses this. */
    if (ioctl(fd, TIOCSRS485, &r) < 0)
        err = errno == ENOTTY || errno == EINVAL || errno == EOPNOTSUPP ? 1 : -errno;
out:
    close(fd);
    return err;
}
