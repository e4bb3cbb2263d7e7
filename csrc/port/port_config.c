/* port_config.c - bringing a device up and down: open, exclusive lock,
 * termios raw 8N1, RS-485 direction mode (kernel / soft RTS / none).
 * All OS calls go through p->be. */
#include "port/port_internal.h"

#include <fcntl.h>
#include <string.h>
#include <sys/file.h>
#include <sys/ioctl.h>

static const struct {
    unsigned baud;
    speed_t speed;
} baud_table[] = {
    {50, B50}, {75, B75}, {110, B110}, {134, B134}, {150, B150},
    {200, B200}, {300, B300}, {600, B600}, {1200, B1200}, {1800, B1800},
    {2400, B2400}, {4800, B4800}, {9600, B9600}, {19200, B19200},
    {38400, B38400}, {57600, B57600}, {115200, B115200},
    {230400, B230400}, {460800, B460800}, {500000, B500000},
    {576000, B576000}, {921600, B921600}, {1000000, B1000000},
    {1152000, B1152000}, {1500000, B1500000}, {2000000, B2000000},
    {2500000, B2500000}, {3000000, B3000000}, {3500000, B3500000},
    {4000000, B4000000},
};

int lf_port_baud_to_speed(unsigned baud, speed_t *out)
{
    for (size_t i = 0; i < sizeof baud_table / sizeof baud_table[0]; i++) {
        if (baud_table[i].baud == baud) {
            *out = baud_table[i].speed;
            return 0;
        }
    }
    return -EINVAL;
}

unsigned lf_port_speed_to_baud(speed_t speed)
{
    for (size_t i = 0; i < sizeof baud_table / sizeof baud_table[0]; i++)
        if (baud_table[i].speed == speed)
            return baud_table[i].baud;
    return 0;
}

unsigned fap_port_baud_rate(size_t i)
{
    return i < sizeof baud_table / sizeof baud_table[0] ? baud_table[i].baud : 0;
}

/* Raw 8N1, no flow control. VMIN=1 VTIME=0 with O_NONBLOCK: an empty queue
 * reads as EAGAIN (with VMIN=0 n_tty returns 0, indistinguishable from a
 * hang-up), and the deadline is ours, via poll. */
static int configure_termios(const fap_port *p, int fd)
{
    speed_t speed;
    if (lf_port_baud_to_speed(p->opt.baud, &speed) < 0)
        return -EINVAL;
    struct termios t;
    if (p->be->tcgetattr(p->ctx, fd, &t) < 0)
        return -errno;
    cfmakeraw(&t);
    t.c_cflag &= ~(tcflag_t)(CSIZE | PARENB | CSTOPB | CRTSCTS);
    t.c_cflag |= CS8 | CLOCAL | CREAD;
    t.c_iflag &= ~(tcflag_t)(IXON | IXOFF | IXANY | INPCK | ISTRIP);
    t.c_cc[VMIN] = 1;
    t.c_cc[VTIME] = 0;
    if (cfsetispeed(&t, speed) < 0 || cfsetospeed(&t, speed) < 0)
        return -EINVAL;
    if (p->be->tcsetattr(p->ctx, fd, TCSANOW, &t) < 0)
        return -errno;
    return 0;
}

static uint32_t us_to_ms_up(unsigned us)
{
    return (uint32_t)(((uint64_t)us + 999u) / 1000u);   /* no wrap near UINT_MAX */
}

/* Kernel RS-485: save the current config, then enable ours. The kernel
 * may clean the struct (clamp delays, drop flags); keep what it returns. */
static int kernel_rs485_enable(const fap_port *p, int fd, lf_port_conn *c)
{
    struct serial_rs485 saved, want;
    memset(&saved, 0, sizeof saved);
    if (p->be->ioctl(p->ctx, fd, TIOCGRS485, &saved) < 0)
        return -errno;
    memset(&want, 0, sizeof want);
    want.flags = SER_RS485_ENABLED;
    /* The flags are the logical RTS level while / after sending. */
    want.flags |= p->opt.rts_active_high ? SER_RS485_RTS_ON_SEND : SER_RS485_RTS_AFTER_SEND;
    if (p->opt.rx_during_tx)
        want.flags |= SER_RS485_RX_DURING_TX;
    want.delay_rts_before_send = us_to_ms_up(p->opt.delay_before_send_us);
    want.delay_rts_after_send = us_to_ms_up(p->opt.delay_after_send_us);
    if (p->be->ioctl(p->ctx, fd, TIOCSRS485, &want) < 0)
        return -errno;
    c->rs485_saved = saved;
    c->rs485_active = want;
    c->rs485_restore = 1;
    return 0;
}

int lf_port_rts(const fap_port *p, int fd, int on)
{
    int bits = TIOCM_RTS;
    /* "on" means the sending level; an active-low transceiver inverts it. */
    int set = p->opt.rts_active_high ? on : !on;
    if (p->be->ioctl(p->ctx, fd, set ? TIOCMBIS : TIOCMBIC, &bits) < 0)
        return -errno;
    return 0;
}

static int setup_direction(const fap_port *p, int fd, lf_port_conn *c)
{
    int err;
    switch (p->opt.rs485_mode) {
    case FAP_RS485_NONE:
        c->mode = FAP_RS485_NONE;
        return 0;
    case FAP_RS485_KERNEL:
        err = kernel_rs485_enable(p, fd, c);
        if (err == 0)
            c->mode = FAP_RS485_KERNEL;
        return err;
    case FAP_RS485_SOFT_RTS:
        /* Start in receive; this also proves the device has an RTS line. */
        err = lf_port_rts(p, fd, 0);
        if (err == 0)
            c->mode = FAP_RS485_SOFT_RTS;
        return err;
    case FAP_RS485_AUTO:
        err = kernel_rs485_enable(p, fd, c);
        if (err == 0) {
            c->mode = FAP_RS485_KERNEL;
            return 0;
        }
        if (lf_port_errno_vanished(-err))
            return err;   /* a dying device is not "no RS-485 support" */
        c->mode = FAP_RS485_NONE;
        c->auto_errno = -err;
        return 0;
    }
    return -EINVAL;
}

int lf_port_conn_open(const fap_port *p, lf_port_conn *c)
{
    memset(c, 0, sizeof *c);
    c->fd = -1;
    int fd = p->be->open(p->ctx, p->path, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return -errno;
    c->fd = fd;
    int err = 0;
    /* flock binds everyone (root bypasses TIOCEXCL); a non-exclusive
     * opener takes a shared lock: it shares with its kind, never with an
     * exclusive owner. */
    if (p->be->flock(p->ctx, fd, (p->opt.exclusive ? LOCK_EX : LOCK_SH) | LOCK_NB) < 0) {
        err = (errno == EWOULDBLOCK) ? -EBUSY : -errno;
        goto fail;
    }
    if (p->opt.exclusive) {
        if (p->be->ioctl(p->ctx, fd, TIOCEXCL, NULL) < 0) {
            err = -errno;
            goto fail;
        }
        c->excl_set = 1;
    }
    err = configure_termios(p, fd);
    if (err)
        goto fail;
    /* Bytes that piled up before we attached are not for us. */
    if (p->be->tcflush(p->ctx, fd, TCIOFLUSH) < 0) {
        err = -errno;
        goto fail;
    }
    err = setup_direction(p, fd, c);
    if (err)
        goto fail;
    return 0;
fail:
    lf_port_conn_close(p, c);
    return err;
}

void lf_port_conn_close(const fap_port *p, lf_port_conn *c)
{
    if (c->fd < 0)
        return;
    /* Best effort: on a vanished device these fail, and that is fine. */
    if (c->rs485_restore)
        (void)p->be->ioctl(p->ctx, c->fd, TIOCSRS485, &c->rs485_saved);
    if (c->excl_set)
        (void)p->be->ioctl(p->ctx, c->fd, TIOCNXCL, NULL);
    (void)p->be->close(p->ctx, c->fd);   /* also drops the flock */
    c->fd = -1;
    c->rs485_restore = 0;
    c->excl_set = 0;
}
