/* Port layer through a fake OS backend: a real pty underneath, but the
 * RS-485 and modem-line ioctls a pty refuses are answered by the fake, which
 * records them (and write / tcdrain / sleeps) in order, and can fail any of
 * them with a chosen errno. Covers kernel mode (the serial_rs485 struct,
 * restore on close, error paths), soft-RTS ordering and its error paths,
 * EINTR and partial writes, and the turnaround wait. */
#include <linux/serial.h>
#include <stdlib.h>
#include <pthread.h>
#include <sys/eventfd.h>
#include <sys/ioctl.h>
#include <sys/stat.h>

#include "fap_port.h"
#include "port/port_device.h"
#include "pty_util.h"
#include "unit.h"

enum ev_kind { EV_RTS_SET, EV_RTS_CLEAR, EV_WRITE, EV_DRAIN, EV_SLEEP, EV_GRS485, EV_SRS485,
               EV_GPIO_OPEN, EV_GPIO_SET, EV_GPIO_CLOSE };

typedef struct fake_ev {
    enum ev_kind kind;
    int64_t value;     /* write: bytes taken; sleep: deadline ns */
    int64_t at_ns;     /* when it was called */
} fake_ev;

typedef struct fake {
    /* the simulated UART's RS-485 state */
    int has_rs485;
    struct serial_rs485 rs485;
    struct serial_rs485 sets[8];   /* every TIOCSRS485 argument, in order */
    int nsets;
    /* errnos to fail with (0 = succeed) */
    int fail_grs485, fail_srs485, fail_mbis, fail_mbic, fail_write, fail_read, fail_drain;
    int eintr_writes;      /* this many writes fail with EINTR first */
    int eintr_reads;
    size_t write_chunk;    /* >0: accept at most this many bytes per write */
    fake_ev ev[64];
    int nev;
    /* the close (kept out of ev[], whose counts the tests check): the
     * c_cflag of the last tcsetattr and the last RTS event before it */
    int closes;
    tcflag_t cflag_set;
    int rts_at_close;   /* EV_RTS_SET / EV_RTS_CLEAR, -1 none */
    /* the GPIO DE line: an eventfd stands for the line fd */
    int gpio_fd, gpio_value, fail_gpio_open, fail_gpio_set;
    char gpio_chip[64];
    unsigned gpio_line;
} fake;

static int count_ev(const fake *f, enum ev_kind k);

static void rec(fake *f, enum ev_kind k, int64_t v)
{
    if (f->nev < 64)
        f->ev[f->nev++] = (fake_ev){k, v, tp_now_ns()};
}

static int f_open(void *c, const char *path, int flags) { (void)c; return open(path, flags); }
static int f_close(void *c, int fd)
{
    fake *f = c;
    if (f->gpio_fd > 0 && fd == f->gpio_fd) {
        rec(f, EV_GPIO_CLOSE, f->gpio_value);
        f->gpio_fd = 0;
        return close(fd);
    }
    f->closes++;
    f->rts_at_close = -1;
    for (int i = f->nev - 1; i >= 0 && f->rts_at_close < 0; i--)
        if (f->ev[i].kind == EV_RTS_SET || f->ev[i].kind == EV_RTS_CLEAR)
            f->rts_at_close = (int)f->ev[i].kind;
    return close(fd);
}
static int f_tcgetattr(void *c, int fd, struct termios *t) { (void)c; return tcgetattr(fd, t); }
static int f_tcsetattr(void *c, int fd, int a, const struct termios *t)
{
    ((fake *)c)->cflag_set = t->c_cflag;
    return tcsetattr(fd, a, t);
}
static int f_tcflush(void *c, int fd, int q) { (void)c; return tcflush(fd, q); }
static int f_flock(void *c, int fd, int op) { (void)c; return lf_port_posix_os.flock(NULL, fd, op); }
static int f_poll(void *c, struct pollfd *p, nfds_t n, int ms) { (void)c; return poll(p, n, ms); }

static int f_ioctl(void *c, int fd, unsigned long req, void *arg)
{
    fake *f = c;
    int fail = 0;
    switch (req) {
    case TIOCGRS485:
        rec(f, EV_GRS485, 0);
        fail = f->has_rs485 ? f->fail_grs485 : ENOTTY;
        if (!fail)
            *(struct serial_rs485 *)arg = f->rs485;
        break;
    case TIOCSRS485:
        rec(f, EV_SRS485, 0);
        fail = f->has_rs485 ? f->fail_srs485 : ENOTTY;
        if (!fail) {
            struct serial_rs485 *r = arg;
            if (f->nsets < 8)
                f->sets[f->nsets++] = *r;
            /* like the PL011 driver: clamp delays to 100 ms, write back */
            if (r->delay_rts_before_send > 100)
                r->delay_rts_before_send = 100;
            if (r->delay_rts_after_send > 100)
                r->delay_rts_after_send = 100;
            f->rs485 = *r;
        }
        break;
    case TIOCMBIS:
    case TIOCMBIC:
        rec(f, req == TIOCMBIS ? EV_RTS_SET : EV_RTS_CLEAR, *(int *)arg);
        fail = req == TIOCMBIS ? f->fail_mbis : f->fail_mbic;
        break;
    default:
        return ioctl(fd, req, arg);   /* TIOCEXCL / TIOCNXCL: the real pty */
    }
    if (fail) {
        errno = fail;
        return -1;
    }
    return 0;
}

static ssize_t f_write(void *c, int fd, const void *b, size_t n)
{
    fake *f = c;
    if (f->eintr_writes > 0) {
        f->eintr_writes--;
        errno = EINTR;
        return -1;
    }
    if (f->fail_write) {
        rec(f, EV_WRITE, -f->fail_write);
        errno = f->fail_write;
        return -1;
    }
    if (f->write_chunk && n > f->write_chunk)
        n = f->write_chunk;
    ssize_t r = write(fd, b, n);
    if (r > 0)
        rec(f, EV_WRITE, r);
    return r;
}

static ssize_t f_read(void *c, int fd, void *b, size_t n)
{
    fake *f = c;
    if (f->eintr_reads > 0) {
        f->eintr_reads--;
        errno = EINTR;
        return -1;
    }
    if (f->fail_read) {
        errno = f->fail_read;
        return -1;
    }
    return read(fd, b, n);
}

static int f_tcdrain(void *c, int fd)
{
    fake *f = c;
    rec(f, EV_DRAIN, 0);
    if (f->fail_drain) {
        errno = f->fail_drain;
        return -1;
    }
    return tcdrain(fd);
}

static void f_sleep_until(void *c, int64_t deadline)
{
    rec(c, EV_SLEEP, deadline);   /* recorded, not slept: the tests stay fast */
}

static int f_gpio_open(void *c, const char *chip, unsigned line, int value)
{
    fake *f = c;
    rec(f, EV_GPIO_OPEN, value);
    if (f->fail_gpio_open)
        return -f->fail_gpio_open;
    snprintf(f->gpio_chip, sizeof f->gpio_chip, "%s", chip);
    f->gpio_line = line;
    f->gpio_value = value;
    f->gpio_fd = eventfd(0, EFD_CLOEXEC);
    return f->gpio_fd;
}

static int f_gpio_set(void *c, int fd, int value)
{
    fake *f = c;
    rec(f, EV_GPIO_SET, value);
    if (fd != f->gpio_fd)
        return -EBADF;
    if (f->fail_gpio_set)
        return -f->fail_gpio_set;
    f->gpio_value = value;
    return 0;
}

static const lf_port_os fake_backend = {
    .open = f_open, .close = f_close, .ioctl = f_ioctl, .tcgetattr = f_tcgetattr,
    .tcsetattr = f_tcsetattr, .tcflush = f_tcflush, .tcdrain = f_tcdrain,
    .flock = f_flock, .read = f_read, .write = f_write, .poll = f_poll,
    .sleep_until = f_sleep_until, .gpio_open = f_gpio_open, .gpio_set = f_gpio_set,
};

static fap_port_options opts_mode(fap_rs485_mode m)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = m;
    return o;
}

/* A UART that had RS-485 configured by someone else before us. */
static void fake_uart(fake *f)
{
    memset(f, 0, sizeof *f);
    f->has_rs485 = 1;
    f->rs485.flags = SER_RS485_RTS_AFTER_SEND;
    f->rs485.delay_rts_before_send = 7;
    f->rs485.delay_rts_after_send = 9;
}

/* ---- kernel mode --------------------------------------------------------- */

static void test_kernel_active_high(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    fake_uart(&f);
    struct serial_rs485 before = f.rs485;
    fap_port_options o = opts_mode(FAP_RS485_KERNEL);
    o.rts_active_high = 1;
    o.delay_before_send_us = 1500;   /* -> 2 ms, rounded up */
    o.delay_after_send_us = 1;       /* -> 1 ms */
    o.rx_during_tx = 1;
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    CHECK_EQ(fap_port_mode(p), FAP_RS485_KERNEL);
    MUST(f.nsets == 1);
    CHECK_EQ(f.sets[0].flags, SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND | SER_RS485_RX_DURING_TX);
    CHECK_EQ(f.sets[0].delay_rts_before_send, 2);
    CHECK_EQ(f.sets[0].delay_rts_after_send, 1);
    /* The kernel toggles RTS itself: a write is write + drain, no RTS ioctl. */
    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "abc", 3), 3);
    MUST(f.nev == 2);
    CHECK_EQ(f.ev[0].kind, EV_WRITE);
    CHECK_EQ(f.ev[1].kind, EV_DRAIN);
    char m[3];
    CHECK_EQ(tp_read_exact(t.master, m, 3, 1000), 3);
    fap_port_close(p);
    MUST(f.nsets == 2);   /* restored on close */
    CHECK_MEM(&f.sets[1], &before, sizeof before);
    CHECK_MEM(&f.rs485, &before, sizeof before);
    tp_close(&t);
}

static void test_kernel_active_low(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    fake_uart(&f);
    fap_port_options o = opts_mode(FAP_RS485_KERNEL);
    o.rts_active_high = 0;
    o.delay_before_send_us = 4294967294u;   /* rounds up without wrapping */
    o.delay_after_send_us = 100000;         /* 100 ms */
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    MUST(f.nsets == 1);
    CHECK_EQ(f.sets[0].flags, SER_RS485_ENABLED | SER_RS485_RTS_AFTER_SEND);
    CHECK_EQ(f.sets[0].delay_rts_before_send, 4294968);
    CHECK_EQ(f.sets[0].delay_rts_after_send, 100);
    /* what the driver made of it */
    uint32_t fl = 0, before_ms = 0, after_ms = 0;
    CHECK_EQ(fap_port_kernel_rs485(p, &fl, &before_ms, &after_ms), 0);
    CHECK_EQ(fl, SER_RS485_ENABLED | SER_RS485_RTS_AFTER_SEND);
    CHECK_EQ(before_ms, 100);
    CHECK_EQ(after_ms, 100);
    CHECK_EQ(fap_port_kernel_rs485(p, NULL, NULL, NULL), 0);
    int hi = -5;
    unsigned b_us = 0, a_us = 0;
    CHECK_EQ(fap_port_rts_settings(p, &hi, &b_us, &a_us), 0);
    CHECK_EQ(hi, 0);
    CHECK_EQ(b_us, 100000);
    CHECK_EQ(a_us, 100000);
    fap_port_close(p);
    CHECK_EQ(f.nsets, 2);
    CHECK_EQ(f.rs485.delay_rts_before_send, 7);
    tp_close(&t);
}

static void test_auto_gets_kernel(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    fake_uart(&f);
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, NULL, &fake_backend, &f) == 0);
    CHECK_EQ(fap_port_mode(p), FAP_RS485_KERNEL);
    CHECK_EQ(fap_port_auto_errno(p), 0);
    /* Nothing given: the board's active-low 7/9 ms stays, only ENABLED added. */
    MUST(f.nsets == 1);
    CHECK_EQ(f.sets[0].flags, SER_RS485_ENABLED | SER_RS485_RTS_AFTER_SEND);
    CHECK_EQ(f.sets[0].delay_rts_before_send, 7);
    CHECK_EQ(f.sets[0].delay_rts_after_send, 9);
    int hi = -5;
    CHECK_EQ(fap_port_rts_settings(p, &hi, NULL, NULL), 0);
    CHECK_EQ(hi, 0);
    fap_port_close(p);
    CHECK_EQ(f.nsets, 2);
    tp_close(&t);
}

/* Given values win one by one; the rest stays as the board has it; what
 * the port reports is the driver's read-back (the fake clamps to 100 ms). */
static void test_kernel_keeps_what_is_not_given(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    fake_uart(&f);
    f.rs485.flags |= SER_RS485_ENABLED | SER_RS485_TERMINATE_BUS | SER_RS485_RX_DURING_TX;
    fap_port_options o = opts_mode(FAP_RS485_KERNEL);
    o.delay_after_send_us = 250000;   /* given: 250 ms, the driver makes it 100 */
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    MUST(f.nsets == 1);
    CHECK_EQ(f.sets[0].flags, SER_RS485_ENABLED | SER_RS485_RTS_AFTER_SEND |
                              SER_RS485_TERMINATE_BUS | SER_RS485_RX_DURING_TX);
    CHECK_EQ(f.sets[0].delay_rts_before_send, 7);
    CHECK_EQ(f.sets[0].delay_rts_after_send, 250);
    uint32_t fl = 0, b = 0, a = 0;
    CHECK_EQ(fap_port_kernel_rs485(p, &fl, &b, &a), 0);
    CHECK_EQ(b, 7);
    CHECK_EQ(a, 100);
    fap_port_close(p);
    fap_port_options_init(&o);
    o.rs485_mode = FAP_RS485_KERNEL;
    o.rts_active_high = 1;
    o.rx_during_tx = 0;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    MUST(f.nsets == 3);
    CHECK_EQ(f.sets[2].flags, SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND | SER_RS485_TERMINATE_BUS);
    CHECK_EQ(f.sets[2].delay_rts_before_send, 7);
    CHECK_EQ(f.sets[2].delay_rts_after_send, 9);
    fap_port_close(p);
    tp_close(&t);
}

/* TIOCGRS485 answered, TIOCSRS485 refused (a plain 8250): explicit KERNEL
 * fails with that errno and nothing stays open; AUTO falls back to NONE. */
static void check_kernel_refused(int get_errno, int set_errno)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    fake_uart(&f);
    f.fail_grs485 = get_errno;
    f.fail_srs485 = set_errno;
    int fds = tp_count_fds();
    fap_port_options o = opts_mode(FAP_RS485_KERNEL);
    fap_port *p = NULL;
    int want = -(get_errno ? get_errno : set_errno);
    CHECK_EQ(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f), want);
    CHECK(p == NULL);
    CHECK_EQ(tp_count_fds(), fds);
    CHECK_EQ(f.nsets, 0);   /* nothing was changed, so nothing to restore */

    o = opts_mode(FAP_RS485_AUTO);
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    CHECK_EQ(fap_port_mode(p), FAP_RS485_NONE);
    CHECK_EQ(fap_port_kernel_rs485(p, NULL, NULL, NULL), -ENOTTY);
    CHECK_EQ(fap_port_auto_errno(p), -want);
    fap_port_close(p);
    CHECK_EQ(f.nsets, 0);
    tp_close(&t);
}

static void test_kernel_set_einval(void) { check_kernel_refused(0, EINVAL); }
static void test_kernel_set_enotty(void) { check_kernel_refused(0, ENOTTY); }
static void test_kernel_get_enotty(void) { check_kernel_refused(ENOTTY, 0); }

static void test_auto_does_not_hide_a_dying_device(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    fake_uart(&f);
    f.fail_grs485 = EIO;
    fap_port *p = NULL;
    CHECK_EQ(lf_port_open_with_backend(&p, t.name, NULL, &fake_backend, &f), -EIO);
    CHECK(p == NULL);
    tp_close(&t);
}

/* ---- soft RTS ------------------------------------------------------------- */

/* One 5-byte write with the direction switched by us (soft RTS, GPIO):
 * on, the delay before, write, drain, the delay after, off. */
static void check_switched_write(const fake *f, enum ev_kind on, int64_t on_value,
                                 enum ev_kind off, int64_t off_value,
                                 int64_t before_ns, int64_t after_ns)
{
    MUST(f->nev == 6);
    CHECK_EQ(f->ev[0].kind, on);
    CHECK_EQ(f->ev[0].value, on_value);
    CHECK_EQ(f->ev[1].kind, EV_SLEEP);
    CHECK(f->ev[1].value >= f->ev[0].at_ns + before_ns);
    CHECK(f->ev[1].value <= f->ev[1].at_ns + before_ns);
    CHECK_EQ(f->ev[2].kind, EV_WRITE);
    CHECK_EQ(f->ev[2].value, 5);
    CHECK_EQ(f->ev[3].kind, EV_DRAIN);
    CHECK_EQ(f->ev[4].kind, EV_SLEEP);
    CHECK(f->ev[4].value >= f->ev[3].at_ns + after_ns);
    CHECK(f->ev[4].value <= f->ev[4].at_ns + after_ns);
    CHECK_EQ(f->ev[5].kind, off);
    CHECK_EQ(f->ev[5].value, off_value);
}

static void check_soft_rts_order(int active_high)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_SOFT_RTS);
    o.rts_active_high = active_high;
    o.delay_before_send_us = 500;
    o.delay_after_send_us = 700;
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    CHECK_EQ(fap_port_mode(p), FAP_RS485_SOFT_RTS);
    /* The pin level: RTS asserted (TIOCMBIS) drives a UART's nRTS pin low. */
    enum ev_kind on = active_high ? EV_RTS_CLEAR : EV_RTS_SET;
    enum ev_kind off = active_high ? EV_RTS_SET : EV_RTS_CLEAR;
    MUST(f.nev == 2);   /* open: is kernel RS-485 on? then RTS to the receive level */
    CHECK_EQ(f.ev[0].kind, EV_GRS485);
    CHECK_EQ(f.ev[1].kind, off);
    CHECK_EQ(f.ev[1].value, TIOCM_RTS);
    CHECK_EQ(f.nsets, 0);   /* no kernel RS-485 here: nothing to switch off */

    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "frame", 5), 5);
    check_switched_write(&f, on, TIOCM_RTS, off, TIOCM_RTS, 500000, 700000);
    char m[5];
    CHECK_EQ(tp_read_exact(t.master, m, 5, 1000), 5);
    CHECK_MEM(m, "frame", 5);

    /* Without delays: on, write, drain, off. */
    fap_port_close(p);
    o.delay_before_send_us = o.delay_after_send_us = 0;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "x", 1), 1);
    MUST(f.nev == 4);
    CHECK_EQ(f.ev[0].kind, on);
    CHECK_EQ(f.ev[1].kind, EV_WRITE);
    CHECK_EQ(f.ev[2].kind, EV_DRAIN);
    CHECK_EQ(f.ev[3].kind, off);
    fap_port_close(p);
    tp_close(&t);
}

static void test_soft_rts_active_high(void) { check_soft_rts_order(1); }
static void test_soft_rts_active_low(void) { check_soft_rts_order(0); }

/* Defect: with HUPCL set (the tty default) the kernel's hang-up at close
 * drops RTS, which is the transmit level of an active-high transceiver.
 * Soft RTS clears HUPCL while open, puts the pin at the receive level
 * before the close and gives back the termios the port had, HUPCL
 * excepted; the other modes leave HUPCL as it was. */
static void check_soft_rts_close(int active_high)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    struct termios orig;   /* a pty master reads and sets the slave's */
    MUST(tcgetattr(t.master, &orig) == 0);
    orig.c_cflag |= HUPCL;   /* a UART's default; a pty slave's lacks it */
    orig.c_lflag |= ICANON;
    MUST(tcsetattr(t.master, TCSANOW, &orig) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_SOFT_RTS);
    o.rts_active_high = active_high;
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    struct termios now;
    MUST(tcgetattr(t.master, &now) == 0);
    CHECK_EQ(now.c_cflag & HUPCL, 0);   /* while open */
    CHECK_EQ(now.c_lflag & ICANON, 0);  /* raw */
    CHECK_EQ(fap_port_write(p, "x", 1), 1);
    f.nev = 0;   /* RTS at the close must come from the close itself */
    fap_port_close(p);
    CHECK_EQ(f.closes, 1);
    CHECK_EQ(f.rts_at_close, active_high ? EV_RTS_SET : EV_RTS_CLEAR);   /* receive level */
    CHECK_EQ(f.cflag_set & HUPCL, 0);
    MUST(tcgetattr(t.master, &now) == 0);
    CHECK_EQ(now.c_cflag & HUPCL, 0);
    CHECK(now.c_lflag & ICANON);         /* the rest as it was */
    CHECK_EQ(cfgetospeed(&now), cfgetospeed(&orig));
    tp_close(&t);
}

static void test_soft_rts_close_active_high(void) { check_soft_rts_close(1); }
static void test_soft_rts_close_active_low(void) { check_soft_rts_close(0); }

static void test_other_modes_keep_hupcl(void)
{
    static const fap_rs485_mode modes[] = {FAP_RS485_NONE, FAP_RS485_KERNEL};
    for (size_t i = 0; i < 2; i++) {
        test_pty t;
        MUST(tp_open(&t) == 0);
        fake f;
        fake_uart(&f);
        struct termios tio;
        MUST(tcgetattr(t.master, &tio) == 0);
        tio.c_cflag |= HUPCL;
        MUST(tcsetattr(t.master, TCSANOW, &tio) == 0);
        fap_port_options o = opts_mode(modes[i]);
        fap_port *p = NULL;
        MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
        struct termios now;
        MUST(tcgetattr(t.master, &now) == 0);
        CHECK(now.c_cflag & HUPCL);
        fap_port_close(p);
        tp_close(&t);
    }
}

/* GPIO DE/RE: the line is requested at the receive level, set to the
 * sending level before the first byte (then the delay), released after
 * tcdrain (and the delay), put back and freed at close; no RTS ioctl. */
static void check_gpio(int active_high)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_GPIO);
    char chip[] = "/dev/gpiochip7";
    o.gpio_chip = chip;
    o.gpio_line = 5;
    o.rts_active_high = active_high;
    o.delay_before_send_us = 400;
    o.delay_after_send_us = 600;
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    chip[0] = 'X';   /* the port keeps its own copy */
    CHECK_EQ(fap_port_mode(p), FAP_RS485_GPIO);
    CHECK(strcmp(fap_rs485_mode_name(FAP_RS485_GPIO), "gpio") == 0);
    CHECK(strcmp(f.gpio_chip, "/dev/gpiochip7") == 0);
    CHECK_EQ(f.gpio_line, 5);
    MUST(f.nev == 1);
    CHECK_EQ(f.ev[0].kind, EV_GPIO_OPEN);
    CHECK_EQ(f.ev[0].value, !active_high);   /* requested at the receive level */
    int hi = -1;
    unsigned b = 0, a = 0;
    CHECK_EQ(fap_port_rts_settings(p, &hi, &b, &a), 0);
    CHECK_EQ(hi, active_high);
    CHECK_EQ(b, 400);
    CHECK_EQ(a, 600);

    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "frame", 5), 5);
    check_switched_write(&f, EV_GPIO_SET, active_high, EV_GPIO_SET, !active_high, 400000, 600000);
    char m[5];
    CHECK_EQ(tp_read_exact(t.master, m, 5, 1000), 5);
    /* send and transact drain too: the line must not drop early */
    f.nev = 0;
    CHECK_EQ(fap_port_send(p, "s", 1), 1);
    CHECK_EQ(count_ev(&f, EV_DRAIN), 1);
    CHECK_EQ(count_ev(&f, EV_RTS_SET) + count_ev(&f, EV_RTS_CLEAR), 0);
    CHECK_EQ(tp_read_exact(t.master, m, 1, 1000), 1);

    /* reopen: the line is freed and requested again */
    f.nev = 0;
    CHECK_EQ(fap_port_reopen(p), 0);
    CHECK_EQ(count_ev(&f, EV_GPIO_CLOSE), 1);
    CHECK_EQ(count_ev(&f, EV_GPIO_OPEN), 1);
    f.nev = 0;
    fap_port_close(p);
    MUST(f.nev == 2);
    CHECK_EQ(f.ev[0].kind, EV_GPIO_SET);
    CHECK_EQ(f.ev[0].value, !active_high);   /* released at close */
    CHECK_EQ(f.ev[1].kind, EV_GPIO_CLOSE);
    tp_close(&t);
}

static void test_gpio_active_high(void) { check_gpio(1); }
static void test_gpio_active_low(void) { check_gpio(0); }

static void test_gpio_errors(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_GPIO);
    fap_port *p = NULL;
    CHECK_EQ(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f), -EINVAL);   /* no chip */
    o.gpio_chip = "";
    CHECK_EQ(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f), -EINVAL);
    o.gpio_chip = "/dev/gpiochip0";
    int fds = tp_count_fds();
    f.fail_gpio_open = ENOENT;
    CHECK_EQ(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f), -ENOENT);
    CHECK_EQ(tp_count_fds(), fds);   /* nothing stays open */
    CHECK(p == NULL);
    f.fail_gpio_open = 0;
    /* a backend without GPIO */
    lf_port_os nogpio = fake_backend;
    nogpio.gpio_open = NULL;
    CHECK_EQ(lf_port_open_with_backend(&p, t.name, &o, &nogpio, &f), -EOPNOTSUPP);
    /* a failing set: nothing is written, the error comes back */
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    f.fail_gpio_set = EIO;
    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "x", 1), -EIO);
    CHECK_EQ(count_ev(&f, EV_WRITE), 0);
    f.fail_gpio_set = 0;
    fap_port_close(p);
    /* the real backend on a path that is no gpiochip */
    o.gpio_chip = "/dev/null";
    CHECK(fap_port_open(&p, t.name, &o) < 0);
    o.gpio_chip = "/nonexistent/gpiochip0";
    CHECK_EQ(fap_port_open(&p, t.name, &o), -ENOENT);
    CHECK_EQ(tp_count_fds(), fds);
    tp_close(&t);
}

/* FTDI latency_timer through a fake sysfs tree: 1 ms while open in soft
 * RTS / GPIO (the default), or always / never as asked; the old value
 * back at close; a timer already at 1 ms, or none, is left alone. */
static int latency_now(const char *file)
{
    char buf[16] = {0};
    FILE *f = fopen(file, "r");
    if (!f)
        return -1;
    int ok = fgets(buf, sizeof buf, f) != NULL;
    fclose(f);
    return ok ? atoi(buf) : -1;
}

static void set_latency(const char *file, int ms)
{
    FILE *f = fopen(file, "w");
    if (f) {
        fprintf(f, "%d\n", ms);
        fclose(f);
    }
}

static void test_latency_timer(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    char root[64], dir[256], file[300], real[256];
    snprintf(root, sizeof root, "/tmp/fap-sysfs-%d", (int)getpid());
    MUST(realpath(t.name, real) != NULL);
    const char *name = strrchr(real, '/') + 1;
    snprintf(dir, sizeof dir, "mkdir -p %s/class/tty/%s/device", root, name);
    MUST(system(dir) == 0);
    snprintf(file, sizeof file, "%s/class/tty/%s/device/latency_timer", root, name);
    set_latency(file, 16);
    lf_port_os be = fake_backend;
    be.sysfs_root = root;
    static const struct { fap_rs485_mode mode; int opt, expect; } cases[] = {
        {FAP_RS485_SOFT_RTS, FAP_PORT_KEEP, 1}, {FAP_RS485_GPIO, FAP_PORT_KEEP, 1},
        {FAP_RS485_NONE, FAP_PORT_KEEP, 16}, {FAP_RS485_NONE, 1, 1},
        {FAP_RS485_SOFT_RTS, 0, 16}, {FAP_RS485_KERNEL, FAP_PORT_KEEP, 16},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        fake f;
        fake_uart(&f);
        fap_port_options o = opts_mode(cases[i].mode);
        o.low_latency = cases[i].opt;
        o.gpio_chip = "/dev/gpiochip0";
        fap_port *p = NULL;
        MUST(lf_port_open_with_backend(&p, t.name, &o, &be, &f) == 0);
        CHECK_EQ(latency_now(file), cases[i].expect);
        if (i == 0) {   /* a replug: the new device's timer is set again */
            set_latency(file, 16);
            CHECK_EQ(fap_port_reopen(p), 0);
            CHECK_EQ(latency_now(file), 1);
        }
        fap_port_close(p);
        CHECK_EQ(latency_now(file), 16);
    }
    /* already at 1 ms: nothing to undo */
    set_latency(file, 1);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_SOFT_RTS);
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &be, &f) == 0);
    fap_port_close(p);
    CHECK_EQ(latency_now(file), 1);
    /* no such file (not an FTDI): opens all the same */
    unlink(file);
    MUST(lf_port_open_with_backend(&p, t.name, &o, &be, &f) == 0);
    fap_port_close(p);
    CHECK_EQ(latency_now(file), -1);
    /* a FIFO (its open would block) and /dev/zero (it never ends) in the
     * file's place: not read, the open goes on at once */
    MUST(mkfifo(file, 0600) == 0);
    int64_t t0 = fap_port_now_ns();
    MUST(lf_port_open_with_backend(&p, t.name, &o, &be, &f) == 0);
    fap_port_close(p);
    CHECK(fap_port_now_ns() - t0 < 1000000000LL);
    unlink(file);
    MUST(symlink("/dev/zero", file) == 0);
    MUST(lf_port_open_with_backend(&p, t.name, &o, &be, &f) == 0);
    fap_port_close(p);
    unlink(file);
    snprintf(dir, sizeof dir, "rm -rf %s", root);
    CHECK_EQ(system(dir), 0);
    tp_close(&t);
}

/* A UART whose kernel RS-485 is on (device tree, an earlier program): the
 * driver would ignore our RTS writes, so soft mode switches it off while
 * open and gives it back at close; polarity and delays not given come
 * from that config (active low, 7/9 ms). */
static void test_soft_rts_turns_kernel_rs485_off(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    fake_uart(&f);
    f.rs485.flags |= SER_RS485_ENABLED;
    struct serial_rs485 before = f.rs485;
    fap_port_options o = opts_mode(FAP_RS485_SOFT_RTS);
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    CHECK_EQ(fap_port_mode(p), FAP_RS485_SOFT_RTS);
    MUST(f.nsets == 1);
    CHECK_EQ(f.sets[0].flags, SER_RS485_RTS_AFTER_SEND);   /* ENABLED cleared, rest kept */
    CHECK_EQ(f.rs485.flags & SER_RS485_ENABLED, 0);
    /* the off switch comes before the first RTS write */
    int i_set = -1, i_rts = -1;
    for (int i = 0; i < f.nev; i++) {
        if (f.ev[i].kind == EV_SRS485 && i_set < 0)
            i_set = i;
        if ((f.ev[i].kind == EV_RTS_SET || f.ev[i].kind == EV_RTS_CLEAR) && i_rts < 0)
            i_rts = i;
    }
    CHECK(i_set >= 0 && i_rts > i_set);
    CHECK_EQ(f.ev[i_rts].kind, EV_RTS_CLEAR);   /* active low: receive = pin high */
    int hi = -5;
    unsigned b_us = 0, a_us = 0;
    CHECK_EQ(fap_port_rts_settings(p, &hi, &b_us, &a_us), 0);
    CHECK_EQ(hi, 0);
    CHECK_EQ(b_us, 7000);
    CHECK_EQ(a_us, 9000);
    CHECK_EQ(fap_port_kernel_rs485(p, NULL, NULL, NULL), -ENOTTY);
    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "s", 1), 1);
    MUST(f.nev == 6);
    CHECK_EQ(f.ev[0].kind, EV_RTS_SET);   /* pin low while sending */
    CHECK(f.ev[1].value >= f.ev[0].at_ns + 7000000);
    CHECK(f.ev[4].value >= f.ev[3].at_ns + 9000000);
    CHECK_EQ(f.ev[5].kind, EV_RTS_CLEAR);
    char m;
    CHECK_EQ(tp_read_exact(t.master, &m, 1, 1000), 1);
    fap_port_close(p);
    MUST(f.nsets == 2);
    CHECK_MEM(&f.rs485, &before, sizeof before);   /* given back exactly */

    /* Given values win over the board's. */
    o.rts_active_high = 1;
    o.delay_before_send_us = 0;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    CHECK_EQ(fap_port_rts_settings(p, &hi, &b_us, &a_us), 0);
    CHECK_EQ(hi, 1);
    CHECK_EQ(b_us, 0);
    CHECK_EQ(a_us, 9000);
    fap_port_close(p);
    CHECK_MEM(&f.rs485, &before, sizeof before);

    /* A refused off switch fails the open: soft RTS could not work. */
    f.fail_srs485 = EPERM;
    CHECK_EQ(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f), -EPERM);
    tp_close(&t);
}

static void test_soft_rts_assert_fails(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_SOFT_RTS);
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    f.fail_mbic = EPERM;   /* active high: sending = pin high = TIOCMBIC */
    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "lost", 4), -EPERM);
    MUST(f.nev == 1);   /* the failed TIOCMBIC, and no write */
    CHECK_EQ(f.ev[0].kind, EV_RTS_CLEAR);
    char m[4];
    CHECK_EQ(tp_read_exact(t.master, m, 4, 50), 0);
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.tx_bytes, 0);
    CHECK_EQ(st.write_errors, 1);
    CHECK(fap_port_fd(p) >= 0);   /* EPERM is not a vanished device */
    f.fail_mbic = 0;
    CHECK_EQ(fap_port_write(p, "ok", 2), 2);
    fap_port_close(p);
    tp_close(&t);
}

/* The one "device gone" list (fap_port_error_is_gone): a write failing
 * with any code on it leaves the port gone until a reopen; others do not. */
static void test_error_is_gone(void)
{
    static const int gone[] = {-EIO, -ENXIO, -ENODEV, -EPIPE, -EBADF, FAP_PORT_ECLOSED};
    static const int kept[] = {0, -EPERM, -EINVAL, -ETIMEDOUT, -EBUSY, -ECANCELED,
                               FAP_PORT_ECOLLISION, EIO, -EAGAIN};
    for (size_t i = 0; i < sizeof gone / sizeof gone[0]; i++)
        CHECK_EQ(fap_port_error_is_gone(gone[i]), 1);
    for (size_t i = 0; i < sizeof kept / sizeof kept[0]; i++)
        CHECK_EQ(fap_port_error_is_gone(kept[i]), 0);

    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, NULL, &fake_backend, &f) == 0);
    f.fail_write = EPIPE;   /* on the list: the port records it */
    CHECK_EQ(fap_port_write(p, "w", 1), -EPIPE);
    CHECK_EQ(fap_port_fd(p), -1);
    CHECK_EQ(fap_port_write(p, "w", 1), -EPIPE);   /* fails fast until a reopen */
    f.fail_write = 0;
    CHECK_EQ(fap_port_reopen(p), 0);
    CHECK_EQ(fap_port_write(p, "z", 1), 1);
    fap_port_close(p);
    tp_close(&t);
}

static void test_soft_rts_open_refused(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    f.fail_mbis = ENOTTY;   /* the receive level of an active-high pin */
    int fds = tp_count_fds();
    fap_port_options o = opts_mode(FAP_RS485_SOFT_RTS);
    fap_port *p = NULL;
    CHECK_EQ(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f), -ENOTTY);
    CHECK(p == NULL);
    CHECK_EQ(tp_count_fds(), fds);
    tp_close(&t);
}

/* A write or drain that fails still releases the bus. */
static void test_soft_rts_released_after_error(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_SOFT_RTS);
    o.delay_after_send_us = 300;
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);

    f.fail_drain = EINVAL;
    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "d", 1), -EINVAL);
    MUST(f.nev == 4);
    CHECK_EQ(f.ev[0].kind, EV_RTS_CLEAR);   /* active high: pin high */
    CHECK_EQ(f.ev[1].kind, EV_WRITE);
    CHECK_EQ(f.ev[2].kind, EV_DRAIN);
    CHECK_EQ(f.ev[3].kind, EV_RTS_SET);   /* no after-delay on error, but released */
    f.fail_drain = 0;

    f.fail_write = ENXIO;   /* USB adapter unplugged mid-frame */
    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "w", 1), -ENXIO);
    MUST(f.nev == 3);
    CHECK_EQ(f.ev[0].kind, EV_RTS_CLEAR);
    CHECK_EQ(f.ev[1].kind, EV_WRITE);
    CHECK_EQ(f.ev[2].kind, EV_RTS_SET);
    CHECK_EQ(fap_port_fd(p), -1);   /* vanished: closed */
    CHECK_EQ(fap_port_write(p, "w", 1), -ENXIO);
    f.fail_write = 0;
    CHECK_EQ(fap_port_reopen(p), 0);
    CHECK_EQ(fap_port_write(p, "z", 1), 1);
    fap_port_close(p);
    tp_close(&t);
}

/* NONE mode never touches the kernel RS-485 config or the RTS line, even
 * on a device that has both. */
static void test_none_touches_nothing(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    fake_uart(&f);
    f.rs485.flags |= SER_RS485_ENABLED;
    struct serial_rs485 before = f.rs485;
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    CHECK_EQ(fap_port_write(p, "n", 1), 1);
    fap_port_close(p);
    for (int i = 0; i < f.nev; i++)
        CHECK(f.ev[i].kind != EV_GRS485 && f.ev[i].kind != EV_SRS485 &&
              f.ev[i].kind != EV_RTS_SET && f.ev[i].kind != EV_RTS_CLEAR);
    CHECK_EQ(f.nsets, 0);
    CHECK_MEM(&f.rs485, &before, sizeof before);
    tp_close(&t);
}

/* ---- EINTR, partial writes, read errors, turnaround ----------------------- */

static void test_eintr_and_partial_writes(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    f.eintr_writes = 2;
    f.eintr_reads = 2;
    f.write_chunk = 3;
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "0123456789", 10), 10);
    int writes = 0;
    for (int i = 0; i < f.nev; i++)
        writes += f.ev[i].kind == EV_WRITE;
    CHECK_EQ(writes, 4);   /* 3 + 3 + 3 + 1 */
    char m[10];
    CHECK_EQ(tp_read_exact(t.master, m, 10, 1000), 10);
    CHECK_MEM(m, "0123456789", 10);
    CHECK_EQ(tp_write_all(t.master, "in", 2, 1000), 2);
    char b[4];
    CHECK_EQ(fap_port_read(p, b, 2, fap_port_now_ns() + 2000000000LL) > 0, 1);
    CHECK_EQ(f.eintr_reads, 0);
    fap_port_close(p);
    tp_close(&t);
}

static void test_read_error_paths(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    char b[4];
    f.fail_read = EOVERFLOW;   /* an odd error: reported, port stays */
    CHECK_EQ(fap_port_read(p, b, 4, 0), -EOVERFLOW);
    CHECK(fap_port_fd(p) >= 0);
    f.fail_read = ENODEV;      /* the device is gone */
    CHECK_EQ(fap_port_read(p, b, 4, 0), -ENODEV);
    CHECK_EQ(fap_port_fd(p), -1);
    f.fail_read = 0;
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.read_errors, 2);
    CHECK_EQ(fap_port_reopen(p), 0);
    CHECK_EQ(fap_port_read(p, b, 4, 0), 0);
    fap_port_close(p);
    tp_close(&t);
}

static void test_turnaround_deadline(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.turnaround_us = 3500;
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    CHECK_EQ(tp_write_all(t.master, "q", 1, 1000), 1);
    char c;
    int64_t before = fap_port_now_ns();
    CHECK_EQ(fap_port_read(p, &c, 1, before + 2000000000LL), 1);
    int64_t after = fap_port_now_ns();
    f.nev = 0;
    CHECK_EQ(fap_port_write(p, "a", 1), 1);
    MUST(f.nev >= 1);
    CHECK_EQ(f.ev[0].kind, EV_SLEEP);   /* before anything is written */
    CHECK(f.ev[0].value >= before + 3500000);
    CHECK(f.ev[0].value <= after + 3500000);
    fap_port_close(p);
    tp_close(&t);
}

/* ---- a G485 transaction on an RS-485 port ---------------------------------- */

/* The bytes fap_py.g485 sends and gets for "read register 7 of device 2"
 * (tests/vectors/g485.json has the format): the pure-Python codec's frames
 * cross the port layer like every other protocol's. Soft RTS: RTS on,
 * request, drain, RTS off, then the reply is read within its deadline. Kernel
 * mode: the UART gets SER_RS485_ENABLED and nobody toggles RTS by hand. */
static const uint8_t g485_request[] = {0xff, 0xff, 0x05, 0x03, 0x07, 0x01, 0xef};
static const uint8_t g485_reply[] = {0xff, 0xff, 0xff, 0x03, 0x07, 0x02, 0xf4};

static void g485_exchange(fap_port *p, test_pty *t)
{
    CHECK_EQ(fap_port_write(p, g485_request, sizeof g485_request), (ssize_t)sizeof g485_request);
    uint8_t req[sizeof g485_request];
    CHECK_EQ(tp_read_exact(t->master, req, sizeof req, 1000), sizeof req);
    CHECK_MEM(req, g485_request, sizeof req);
    CHECK_EQ(write(t->master, g485_reply, sizeof g485_reply), (ssize_t)sizeof g485_reply);
    uint8_t got[16];
    size_t have = 0;
    int64_t deadline = fap_port_now_ns() + 2000000000LL;
    while (have < sizeof g485_reply) {
        ssize_t r = fap_port_read(p, got + have, sizeof got - have, deadline);
        MUST(r > 0);
        have += (size_t)r;
    }
    CHECK_EQ(have, sizeof g485_reply);
    CHECK_MEM(got, g485_reply, sizeof g485_reply);
}

static void test_g485_transaction_soft_rts(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    memset(&f, 0, sizeof f);
    fap_port_options o = opts_mode(FAP_RS485_SOFT_RTS);
    o.baud = 115200;
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    f.nev = 0;
    g485_exchange(p, &t);
    MUST(f.nev == 4);
    /* default polarity: pin high while sending, i.e. the modem RTS bit cleared */
    CHECK_EQ(f.ev[0].kind, EV_RTS_CLEAR);
    CHECK_EQ(f.ev[1].kind, EV_WRITE);
    CHECK_EQ(f.ev[1].value, (int64_t)sizeof g485_request);
    CHECK_EQ(f.ev[2].kind, EV_DRAIN);
    CHECK_EQ(f.ev[3].kind, EV_RTS_SET);   /* released before the reply comes */
    fap_port_close(p);
    tp_close(&t);
}

static void test_g485_transaction_kernel(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fake f;
    fake_uart(&f);
    fap_port_options o = opts_mode(FAP_RS485_KERNEL);
    fap_port *p = NULL;
    MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
    CHECK(f.rs485.flags & SER_RS485_ENABLED);
    f.nev = 0;
    g485_exchange(p, &t);
    for (int i = 0; i < f.nev; i++)
        CHECK(f.ev[i].kind != EV_RTS_SET && f.ev[i].kind != EV_RTS_CLEAR);
    fap_port_close(p);
    tp_close(&t);
}

/* fap_port_transact: stale input is dropped (read, not tcflush: queued
 * output survives), the request goes out, the reply's first chunk comes
 * back in the same call. tcdrain() only where something depends on it:
 * soft RTS (release after the last bit); not in mode none or kernel. */
typedef struct responder {
    int fd;
} responder;

static void *respond(void *arg)
{
    responder *r = arg;
    uint8_t req[sizeof g485_request];
    if (tp_read_exact(r->fd, req, sizeof req, 2000) == sizeof req &&
        memcmp(req, g485_request, sizeof req) == 0)
        (void)!write(r->fd, g485_reply, sizeof g485_reply);
    return NULL;
}

static void transact_once(fap_port *p, test_pty *t)
{
    static const uint8_t stale[] = {0xff, 0xff, 0xff, 0x03, 0x09, 0x00, 0x00};
    CHECK_EQ(write(t->master, stale, sizeof stale), (ssize_t)sizeof stale);
    /* the stale bytes have reached the port before the call */
    int64_t until = fap_port_now_ns() + 1000000000LL;
    int queued = 0;
    while (fap_port_now_ns() < until && queued < (int)sizeof stale) {
        struct pollfd pf = {.fd = fap_port_fd(p), .events = POLLIN};
        if (poll(&pf, 1, 100) > 0)
            queued = (int)sizeof stale;
    }
    MUST(queued);
    responder r = {.fd = t->master};
    pthread_t th;
    MUST(pthread_create(&th, NULL, respond, &r) == 0);
    uint8_t got[16];
    size_t have = 0;
    int64_t deadline = fap_port_now_ns() + 2000000000LL;
    ssize_t n = fap_port_transact(p, g485_request, sizeof g485_request, got, sizeof got, deadline);
    MUST(n > 0);
    have = (size_t)n;
    while (have < sizeof g485_reply) {
        n = fap_port_read(p, got + have, sizeof got - have, deadline);
        MUST(n > 0);
        have += (size_t)n;
    }
    pthread_join(th, NULL);
    CHECK_EQ(have, sizeof g485_reply);
    CHECK_MEM(got, g485_reply, sizeof g485_reply);
}

static int count_ev(const fake *f, enum ev_kind k)
{
    int c = 0;
    for (int i = 0; i < f->nev; i++)
        c += f->ev[i].kind == k;
    return c;
}

static void test_transact_modes(void)
{
    static const fap_rs485_mode modes[] = {FAP_RS485_NONE, FAP_RS485_KERNEL, FAP_RS485_SOFT_RTS};
    for (size_t i = 0; i < sizeof modes / sizeof modes[0]; i++) {
        test_pty t;
        MUST(tp_open(&t) == 0);
        fake f;
        fake_uart(&f);
        fap_port_options o = opts_mode(modes[i]);
        fap_port *p = NULL;
        MUST(lf_port_open_with_backend(&p, t.name, &o, &fake_backend, &f) == 0);
        f.nev = 0;
        transact_once(p, &t);
        CHECK_EQ(count_ev(&f, EV_WRITE), 1);
        CHECK_EQ(count_ev(&f, EV_DRAIN), modes[i] == FAP_RS485_SOFT_RTS ? 1 : 0);
        if (modes[i] == FAP_RS485_SOFT_RTS) {
            /* on, (delay), write, drain, (delay), off: as fap_port_write */
            int w = 0;
            while (w < f.nev && f.ev[w].kind != EV_WRITE)
                w++;
            MUST(w + 1 < f.nev);
            CHECK_EQ(f.ev[w + 1].kind, EV_DRAIN);
            CHECK(f.ev[f.nev - 1].kind == EV_RTS_SET || f.ev[f.nev - 1].kind == EV_RTS_CLEAR);
        }
        /* fap_port_write itself still drains in every mode */
        f.nev = 0;
        CHECK_EQ(fap_port_write(p, "x", 1), 1);
        CHECK_EQ(count_ev(&f, EV_DRAIN), 1);
        char m;
        CHECK_EQ(tp_read_exact(t.master, &m, 1, 1000), 1);
        /* fap_port_send: the same write, drained only where soft RTS needs it */
        f.nev = 0;
        CHECK_EQ(fap_port_send(p, "z", 1), 1);
        CHECK_EQ(count_ev(&f, EV_WRITE), 1);
        CHECK_EQ(count_ev(&f, EV_DRAIN), modes[i] == FAP_RS485_SOFT_RTS ? 1 : 0);
        CHECK_EQ(tp_read_exact(t.master, &m, 1, 1000), 1);
        CHECK_EQ(m, 'z');
        CHECK_EQ(fap_port_send(p, NULL, 1), -EINVAL);
        CHECK_EQ(fap_port_send(p, "z", 0), 0);
        /* no reply awaited (cap 0); bad arguments */
        CHECK_EQ(fap_port_transact(p, "y", 1, NULL, 0, 0), 0);
        CHECK_EQ(tp_read_exact(t.master, &m, 1, 1000), 1);
        CHECK_EQ(fap_port_transact(p, NULL, 1, NULL, 0, 0), -EINVAL);
        CHECK_EQ(fap_port_transact(NULL, "y", 1, NULL, 0, 0), -EINVAL);
        CHECK_EQ(fap_port_transact(p, "y", 1, NULL, 4, 0), -EINVAL);
        fap_port_close(p);
        tp_close(&t);
    }
}

UNIT_MAIN(UNIT(test_transact_modes), UNIT(test_kernel_active_high), UNIT(test_kernel_active_low),
          UNIT(test_auto_gets_kernel), UNIT(test_kernel_set_einval),
          UNIT(test_kernel_set_enotty), UNIT(test_kernel_get_enotty),
          UNIT(test_auto_does_not_hide_a_dying_device),
          UNIT(test_soft_rts_active_high), UNIT(test_soft_rts_active_low),
          UNIT(test_soft_rts_close_active_high), UNIT(test_soft_rts_close_active_low),
          UNIT(test_other_modes_keep_hupcl),
          UNIT(test_gpio_active_high), UNIT(test_gpio_active_low), UNIT(test_gpio_errors),
          UNIT(test_latency_timer),
          UNIT(test_soft_rts_turns_kernel_rs485_off), UNIT(test_kernel_keeps_what_is_not_given),
          UNIT(test_none_touches_nothing),
          UNIT(test_soft_rts_assert_fails), UNIT(test_soft_rts_open_refused),
          UNIT(test_error_is_gone),
          UNIT(test_soft_rts_released_after_error),
          UNIT(test_eintr_and_partial_writes), UNIT(test_read_error_paths),
          UNIT(test_turnaround_deadline),
          UNIT(test_g485_transaction_soft_rts), UNIT(test_g485_transaction_kernel))
