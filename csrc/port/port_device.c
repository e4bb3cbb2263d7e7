/* port_device.c - the device transport: a tty as a line (port_backend.h).
 * The only place that builds a struct termios or issues a tty ioctl, all
 * through the OS table it was made over (lf_port_os, port_device.h): the
 * real one, or a test's fake around a pty. */
#include "port/port_device.h"

#include <errno.h>
#include <fcntl.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/ioctl.h>

typedef struct lf_port_dev {
    lf_port_transport tr;         /* this device's table (os's options copied in) */
    const lf_port_os *os;
    void *os_ctx;
    struct termios tio_saved;     /* set_line(hold_rts): termios before we configured */
    int tio_saved_ok;             /* tio_saved holds it (restore_line: put it back) */
} lf_port_dev;

static int dev_open(void *ctx, const char *path)
{
    lf_port_dev *d = ctx;
    int fd = d->os->open(d->os_ctx, path, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    return fd < 0 ? -errno : fd;
}

static int dev_close(void *ctx, int fd)
{
    lf_port_dev *d = ctx;
    return d->os->close(d->os_ctx, fd);
}

/* Raw 8N1, no flow control. VMIN=1 VTIME=0 with O_NONBLOCK: an empty queue
 * reads as EAGAIN (with VMIN=0 n_tty returns 0, indistinguishable from a
 * hang-up), and the deadline is ours, via poll. Soft RTS (hold_rts) also
 * clears HUPCL: the hang-up at close drops RTS, the transmit level of an
 * active-high transceiver (see dev_restore_line). */
static int dev_set_line(void *ctx, int fd, unsigned baud, int hold_rts)
{
    lf_port_dev *d = ctx;
    d->tio_saved_ok = 0;
    speed_t speed;
    if (lf_port_baud_to_speed(baud, &speed) < 0)
        return -EINVAL;
    struct termios t;
    if (d->os->tcgetattr(d->os_ctx, fd, &t) < 0)
        return -errno;
    if (hold_rts) {
        d->tio_saved = t;
        d->tio_saved_ok = 1;
        t.c_cflag &= ~(tcflag_t)HUPCL;
    }
    cfmakeraw(&t);
    t.c_cflag &= ~(tcflag_t)(CSIZE | PARENB | CSTOPB | CRTSCTS);
    t.c_cflag |= CS8 | CLOCAL | CREAD;
    t.c_iflag &= ~(tcflag_t)(IXON | IXOFF | IXANY | INPCK | ISTRIP);
    t.c_cc[VMIN] = 1;
    t.c_cc[VTIME] = 0;
    if (cfsetispeed(&t, speed) < 0 || cfsetospeed(&t, speed) < 0)
        return -EINVAL;
    if (d->os->tcsetattr(d->os_ctx, fd, TCSANOW, &t) < 0)
        return -errno;
    return 0;
}

/* Soft RTS at close (the pin is at the receive level already): the termios
 * the port had, except the bits that would move RTS: HUPCL stays cleared
 * (the close would drop RTS), and no CRTSCTS (the kernel would drive RTS)
 * or B0 (drops it). TCSANOW is safe: every soft-RTS write drained. Best
 * effort: on a vanished device it fails, and that is fine. */
static void dev_restore_line(void *ctx, int fd, unsigned baud)
{
    lf_port_dev *d = ctx;
    if (!d->tio_saved_ok)
        return;   /* set_line never read it */
    d->tio_saved_ok = 0;
    struct termios t = d->tio_saved;
    t.c_cflag &= ~(tcflag_t)(HUPCL | CRTSCTS);
    if (cfgetospeed(&t) == B0) {
        speed_t speed;
        if (lf_port_baud_to_speed(baud, &speed) == 0)
            (void)cfsetospeed(&t, speed);
    }
    (void)d->os->tcsetattr(d->os_ctx, fd, TCSANOW, &t);
}

static int dev_flush(void *ctx, int fd, int queue)
{
    lf_port_dev *d = ctx;
    int q = queue == LF_PORT_FLUSH_IN ? TCIFLUSH : queue == LF_PORT_FLUSH_OUT ? TCOFLUSH
                                                                              : TCIOFLUSH;
    return d->os->tcflush(d->os_ctx, fd, q) < 0 ? -errno : 0;
}

static int dev_drain(void *ctx, int fd)
{
    lf_port_dev *d = ctx;
    while (d->os->tcdrain(d->os_ctx, fd) < 0) {
        if (errno != EINTR)
            return -errno;
    }
    return 0;
}

static int dev_rs485_get(void *ctx, int fd, struct serial_rs485 *r)
{
    lf_port_dev *d = ctx;
    return d->os->ioctl(d->os_ctx, fd, TIOCGRS485, r) < 0 ? -errno : 0;
}

static int dev_rs485_set(void *ctx, int fd, const struct serial_rs485 *r)
{
    lf_port_dev *d = ctx;
    struct serial_rs485 copy = *r;   /* ioctl(2) takes a non-const pointer */
    return d->os->ioctl(d->os_ctx, fd, TIOCSRS485, &copy) < 0 ? -errno : 0;
}

/* The modem-control RTS bit is the complement of the pin on a UART (PL011,
 * 16550: RTS asserted = nRTS pin low), so a high pin is TIOCMBIC. */
static int dev_rts(void *ctx, int fd, int pin_high)
{
    lf_port_dev *d = ctx;
    int bits = TIOCM_RTS;
    return d->os->ioctl(d->os_ctx, fd, pin_high ? TIOCMBIC : TIOCMBIS, &bits) < 0 ? -errno : 0;
}

/* flock binds everyone (root bypasses TIOCEXCL); a non-exclusive opener
 * takes a shared lock: it shares with its kind, never with an exclusive
 * owner. Exclusive also sets TIOCEXCL (undone by dev_unlock). */
static int dev_lock(void *ctx, int fd, int exclusive)
{
    lf_port_dev *d = ctx;
    if (d->os->flock(d->os_ctx, fd, (exclusive ? LOCK_EX : LOCK_SH) | LOCK_NB) < 0)
        return errno == EWOULDBLOCK ? -EBUSY : -errno;
    if (exclusive && d->os->ioctl(d->os_ctx, fd, TIOCEXCL, NULL) < 0)
        return -errno;   /* the close drops the flock */
    return 0;
}

static void dev_unlock(void *ctx, int fd)
{
    lf_port_dev *d = ctx;
    (void)d->os->ioctl(d->os_ctx, fd, TIOCNXCL, NULL);
}

/* The line status register (TIOCSERGETLSR: 8250, PL011): TEMT. */
static int dev_tx_empty(void *ctx, int fd)
{
    lf_port_dev *d = ctx;
    unsigned lsr = 0;
    if (d->os->ioctl(d->os_ctx, fd, TIOCSERGETLSR, &lsr) < 0)
        return -errno;
    return (lsr & TIOCSER_TEMT) != 0;
}

static ssize_t dev_read(void *ctx, int fd, void *buf, size_t n)
{
    lf_port_dev *d = ctx;
    return d->os->read(d->os_ctx, fd, buf, n);
}

static ssize_t dev_write(void *ctx, int fd, const void *buf, size_t n)
{
    lf_port_dev *d = ctx;
    return d->os->write(d->os_ctx, fd, buf, n);
}

static int dev_poll(void *ctx, struct pollfd *fds, nfds_t n, int timeout_ms)
{
    lf_port_dev *d = ctx;
    return d->os->poll(d->os_ctx, fds, n, timeout_ms);
}

static void dev_sleep_until(void *ctx, int64_t deadline_ns)
{
    lf_port_dev *d = ctx;
    d->os->sleep_until(d->os_ctx, deadline_ns);
}

static int64_t dev_now(void *ctx)
{
    lf_port_dev *d = ctx;
    return d->os->now(d->os_ctx);
}

static int dev_gpio_open(void *ctx, const char *chip, unsigned line, int value)
{
    lf_port_dev *d = ctx;
    return d->os->gpio_open(d->os_ctx, chip, line, value);
}

static int dev_gpio_set(void *ctx, int line_fd, int value)
{
    lf_port_dev *d = ctx;
    return d->os->gpio_set(d->os_ctx, line_fd, value);
}

static void dev_destroy(void *ctx)
{
    free(ctx);
}

static const lf_port_transport dev_template = {
    .open = dev_open,
    .close = dev_close,
    .set_line = dev_set_line,
    .restore_line = dev_restore_line,
    .flush = dev_flush,
    .drain = dev_drain,
    .rs485_get = dev_rs485_get,
    .rs485_set = dev_rs485_set,
    .rts = dev_rts,
    .lock = dev_lock,
    .unlock = dev_unlock,
    .tx_empty = dev_tx_empty,
    .read = dev_read,
    .write = dev_write,
    .poll = dev_poll,
    .sleep_until = dev_sleep_until,
    .destroy = dev_destroy,
};

int lf_port_device_new(const lf_port_os *os, void *os_ctx, const lf_port_transport **tr,
                       void **ctx)
{
    if (!os || !tr || !ctx)
        return -EINVAL;
    lf_port_dev *d = calloc(1, sizeof *d);
    if (!d)
        return -ENOMEM;
    d->os = os;
    d->os_ctx = os_ctx;
    d->tr = dev_template;
    /* what the OS table has, the device has; what it lacks, the device cannot */
    d->tr.now = os->now ? dev_now : NULL;
    d->tr.gpio_open = os->gpio_open ? dev_gpio_open : NULL;
    d->tr.gpio_set = os->gpio_set ? dev_gpio_set : NULL;
    d->tr.sysfs_root = os->sysfs_root;
    d->tr.caps = os->caps;
    *tr = &d->tr;
    *ctx = d;
    return 0;
}
