/* rs485_checks.c - runs inside the QEMU guest on the PL011 (/dev/ttyAMA0).
 *
 * Prints one line per result on stdout (the guest console, hvc0):
 *   RESULT <name> PASS|FAIL <detail>   decided here (TIOCGRS485 read-backs)
 *   TRACE <name> <key=value ...>       decided by the host from QEMU's
 *                                      pl011_write trace (run.py): each
 *                                      trace check sends its own payload,
 *                                      so the host finds its bytes there.
 * Only the public fap_port API plus raw ioctls on a second descriptor
 * (opened only while no fap_port is open: every open of a tty raises RTS). */
#include <errno.h>
#include <fcntl.h>
#include <linux/gpio.h>
#include <linux/serial.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "fap_port.h"

static const char *dev = "/dev/ttyAMA0";
/* GPIO mode: the PL061 beside the PL011; line 1 is free (3 is the virt
 * machine's power button). run.py's GPIO_LINE must match. */
static const char *gpio_chip = "/dev/gpiochip0";
enum { GPIO_LINE = 1 };
static int failures;

static void result(const char *name, int ok, const char *fmt, ...)
{
    char detail[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    printf("RESULT %s %s %s\n", name, ok ? "PASS" : "FAIL", detail);
    fflush(stdout);
    failures += !ok;
}

static void msleep(int ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    while (nanosleep(&ts, &ts) < 0 && errno == EINTR) {}
}

static const char *fmt_rs(const struct serial_rs485 *r)
{
    static char buf[4][96];
    static int i;
    char *b = buf[i++ & 3];
    snprintf(b, 96, "{flags=0x%x before=%u after=%u}", r->flags,
             r->delay_rts_before_send, r->delay_rts_after_send);
    return b;
}

/* The device's config through a descriptor of our own (no port open). */
static int raw_get(struct serial_rs485 *r)
{
    int fd = open(dev, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0)
        return -errno;
    memset(r, 0, sizeof *r);
    int rc = ioctl(fd, TIOCGRS485, r) < 0 ? -errno : 0;
    close(fd);
    return rc;
}

static int raw_set(const struct serial_rs485 *want, struct serial_rs485 *got)
{
    int fd = open(dev, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0)
        return -errno;
    struct serial_rs485 r = *want;
    int rc = ioctl(fd, TIOCSRS485, &r) < 0 ? -errno : 0;
    if (rc == 0 && got) {
        memset(got, 0, sizeof *got);
        rc = ioctl(fd, TIOCGRS485, got) < 0 ? -errno : 0;
    }
    close(fd);
    return rc;
}

/* What the board "has": the state a device tree or an earlier program left. */
static struct serial_rs485 board(uint32_t flags, uint32_t before, uint32_t after)
{
    struct serial_rs485 r;
    memset(&r, 0, sizeof r);
    r.flags = flags;
    r.delay_rts_before_send = before;
    r.delay_rts_after_send = after;
    struct serial_rs485 got;
    if (raw_set(&r, &got) < 0) {
        result("preset", 0, "TIOCSRS485 %s: %s", fmt_rs(&r), strerror(errno));
        exit(1);
    }
    return got;
}

/* The port's device fd, found in /proc (fap_port_fd hands out an epoll fd):
 * reading the kernel's view while the port is open, without a second open. */
static int port_dev_fd(void)
{
    for (int fd = 3; fd < 256; fd++) {
        char link[64], target[64];
        snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
        ssize_t n = readlink(link, target, sizeof target - 1);
        if (n > 0) {
            target[n] = 0;
            if (strcmp(target, dev) == 0)
                return fd;
        }
    }
    return -1;
}

static int live_get(struct serial_rs485 *r)
{
    int fd = port_dev_fd();
    memset(r, 0, sizeof *r);
    if (fd < 0 || ioctl(fd, TIOCGRS485, r) < 0)
        return -1;
    return 0;
}

static int same(const struct serial_rs485 *a, const struct serial_rs485 *b)
{
    return memcmp(a, b, sizeof *a) == 0;
}

static fap_port *open_port(fap_rs485_mode mode, int high, unsigned before_us, unsigned after_us)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = mode;
    if (mode == FAP_RS485_GPIO) {
        o.gpio_chip = gpio_chip;
        o.gpio_line = GPIO_LINE;
    }
    if (high != 2)
        o.rts_active_high = high;
    if (before_us != 1u)
        o.delay_before_send_us = before_us;
    if (after_us != 1u)
        o.delay_after_send_us = after_us;
    fap_port *p = NULL;
    int err = fap_port_open(&p, dev, &o);
    if (err) {
        result("open", 0, "mode %d: %s", (int)mode, fap_port_strerror(err));
        return NULL;
    }
    return p;
}
#define NOT_GIVEN 2, 1u, 1u   /* open_port: options left at their defaults */

/* Kernel mode with given values: the driver cleans them; the port reports
 * the read-back; the original comes back at close. */
static void check_kernel_readback(void)
{
    struct serial_rs485 orig = board(SER_RS485_ENABLED | SER_RS485_RTS_AFTER_SEND, 7, 9);
    fap_port *p = open_port(FAP_RS485_KERNEL, 1, 250000, 3000);
    if (!p)
        return;
    struct serial_rs485 live;
    int lr = live_get(&live);
    uint32_t fl = 0, b = 0, a = 0;
    int gr = fap_port_kernel_rs485(p, &fl, &b, &a);
    int ok = lr == 0 && live.flags == (SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND) &&
             live.delay_rts_before_send == 100 && live.delay_rts_after_send == 3;
    result("kernel_given_values_readback", ok, "asked high 250/3 ms, kernel has %s", fmt_rs(&live));
    result("kernel_port_reports_accepted", gr == 0 && fl == live.flags &&
           b == live.delay_rts_before_send && a == live.delay_rts_after_send,
           "fap_port_kernel_rs485 {flags=0x%x before=%u after=%u}", fl, b, a);
    fap_port_close(p);
    struct serial_rs485 after;
    raw_get(&after);
    result("kernel_restored_at_close", same(&after, &orig), "board %s, after close %s",
           fmt_rs(&orig), fmt_rs(&after));
}

/* The driver's cleaning, as the port layer's docs describe it. */
static void check_kernel_cleaning(void)
{
    struct serial_rs485 w, got;
    memset(&w, 0, sizeof w);
    w.flags = SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND;
    w.delay_rts_before_send = 500;
    w.delay_rts_after_send = 101;
    int rc = raw_set(&w, &got);
    result("kernel_clamps_delays_100ms", rc == 0 && got.delay_rts_before_send == 100 &&
           got.delay_rts_after_send == 100, "500/101 -> %s", fmt_rs(&got));
    w.flags = SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND | SER_RS485_TERMINATE_BUS;
    w.delay_rts_before_send = w.delay_rts_after_send = 0;
    rc = raw_set(&w, &got);
    result("kernel_drops_terminate_bus", rc == 0 && !(got.flags & SER_RS485_TERMINATE_BUS),
           "-> %s", fmt_rs(&got));
    w.flags = SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND | SER_RS485_RTS_AFTER_SEND;
    rc = raw_set(&w, &got);
    result("kernel_both_rts_flags_keeps_on_send", rc == 0 &&
           (got.flags & (SER_RS485_RTS_ON_SEND | SER_RS485_RTS_AFTER_SEND)) == SER_RS485_RTS_ON_SEND,
           "-> %s", fmt_rs(&got));
    w.flags = SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND | SER_RS485_ADDRB;
    rc = raw_set(&w, &got);
    result("kernel_addrb_einval", rc == -EINVAL, "rc %d (%s)", rc, strerror(-rc));
}

/* Defect 3: nothing given -> the board's config stays (only ENABLED added). */
static void check_kernel_keeps_board(fap_rs485_mode mode, const char *name)
{
    struct serial_rs485 orig = board(SER_RS485_ENABLED | SER_RS485_RTS_AFTER_SEND, 7, 9);
    fap_port *p = open_port(mode, NOT_GIVEN);
    if (!p)
        return;
    struct serial_rs485 live;
    live_get(&live);
    result(name, fap_port_mode(p) == FAP_RS485_KERNEL && same(&live, &orig),
           "mode %s, board %s, while open %s", fap_rs485_mode_name(fap_port_mode(p)),
           fmt_rs(&orig), fmt_rs(&live));
    fap_port_close(p);
}

static void check_reopen_restore(void)
{
    struct serial_rs485 orig = board(SER_RS485_RTS_AFTER_SEND, 7, 9);   /* off */
    fap_port *p = open_port(FAP_RS485_KERNEL, 1, 2000, 3000);
    if (!p)
        return;
    int rr = fap_port_reopen(p);
    struct serial_rs485 live;
    live_get(&live);
    result("kernel_after_reopen", rr == 0 && live.flags == (SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND) &&
           live.delay_rts_before_send == 2 && live.delay_rts_after_send == 3,
           "reopen %d, while open %s", rr, fmt_rs(&live));
    fap_port_close(p);
    struct serial_rs485 after;
    raw_get(&after);
    result("kernel_restored_after_reopen", same(&after, &orig), "board %s, after close %s",
           fmt_rs(&orig), fmt_rs(&after));
}

static void check_auto(void)
{
    board(0, 0, 0);
    fap_port *p = open_port(FAP_RS485_AUTO, NOT_GIVEN);
    if (!p)
        return;
    result("auto_picks_kernel", fap_port_mode(p) == FAP_RS485_KERNEL, "mode %s auto_errno %d",
           fap_rs485_mode_name(fap_port_mode(p)), fap_port_auto_errno(p));
    fap_port_close(p);
}

/* A trace check: open, idle, send a payload of its own, idle, close. The
 * host finds the payload's data-register writes in QEMU's trace and the
 * control-register (RTS) writes around them. */
static void trace_check(const char *name, fap_rs485_mode mode, int high,
                        unsigned before_ms, unsigned after_ms, struct serial_rs485 preset)
{
    struct serial_rs485 orig = board(preset.flags, preset.delay_rts_before_send,
                                     preset.delay_rts_after_send);
    fap_port *p = open_port(mode, high, before_ms * 1000u, after_ms * 1000u);
    if (!p)
        return;
    if (preset.flags & SER_RS485_ENABLED) {
        struct serial_rs485 live;
        live_get(&live);
        char n[96];
        snprintf(n, sizeof n, "%s_kernel_rs485_off_while_open", name);
        result(n, !(live.flags & SER_RS485_ENABLED), "board %s, while open %s",
               fmt_rs(&orig), fmt_rs(&live));
    }
    msleep(150);   /* idle after open: the receive level must hold */
    char payload[32];
    int n = snprintf(payload, sizeof payload, "<%s>", name);
    ssize_t w = fap_port_write(p, payload, (size_t)n);
    msleep(150);
    fap_port_close(p);
    struct serial_rs485 after;
    raw_get(&after);
    char rn[96];
    snprintf(rn, sizeof rn, "%s_restored_at_close", name);
    result(rn, w == n && same(&after, &orig), "write %zd, board %s, after close %s", w,
           fmt_rs(&orig), fmt_rs(&after));
    printf("TRACE %s mode=%s high=%d before_ms=%u after_ms=%u payload=", name,
           fap_rs485_mode_name(mode), high, before_ms, after_ms);
    for (int i = 0; i < n; i++)
        printf("%02x", (unsigned char)payload[i]);
    printf("\n");
    fflush(stdout);
}

/* The GPIO line's level now, read without changing it: a v2 request with
 * neither INPUT nor OUTPUT keeps the direction as it is (and an output's
 * value). 0/1, or -errno. */
static int gpio_level(int *value_out)
{
    int cfd = open(gpio_chip, O_RDWR);
    if (cfd < 0)
        return -errno;
    struct gpio_v2_line_request req;
    memset(&req, 0, sizeof req);
    req.offsets[0] = GPIO_LINE;
    req.num_lines = 1;
    strcpy(req.consumer, "rs485_checks");
    int rc = ioctl(cfd, GPIO_V2_GET_LINE_IOCTL, &req) < 0 ? -errno : 0;
    close(cfd);
    if (rc)
        return rc;
    struct gpio_v2_line_values v = {.mask = 1};
    rc = ioctl(req.fd, GPIO_V2_LINE_GET_VALUES_IOCTL, &v) < 0 ? -errno : 0;
    close(req.fd);
    *value_out = (int)(v.bits & 1);
    return rc;
}

/* Known levels in the trace before the GPIO checks (PL061 traces changes
 * only): drive the line 1 then 0 once, as an output. */
static void gpio_prime(void)
{
    fap_port *p = open_port(FAP_RS485_GPIO, 0, 0, 0);   /* requested high (receive) */
    if (p)
        fap_port_close(p);
    p = open_port(FAP_RS485_GPIO, 1, 0, 0);             /* requested low */
    if (p)
        fap_port_close(p);
}

/* The DE line after a GPIO-mode port closed, and after a process that
 * wrote and exited without closing: at the receive level. */
static void gpio_released(int high)
{
    fap_port *p = open_port(FAP_RS485_GPIO, high, 0, 0);
    if (!p)
        return;
    ssize_t w = fap_port_write(p, "g", 1);
    fap_port_close(p);
    int v = -1, rc = gpio_level(&v);
    char name[64];
    snprintf(name, sizeof name, "gpio_%s_released_at_close", high ? "high" : "low");
    result(name, w == 1 && rc == 0 && v == !high, "write %zd, line %d level %d (rc %d)", w,
           GPIO_LINE, v, rc);
    fflush(stdout);
    pid_t child = fork();
    if (child == 0) {
        fap_port *q = open_port(FAP_RS485_GPIO, high, 0, 0);
        _exit(q && fap_port_write(q, "e", 1) == 1 ? 0 : 1);   /* no close */
    }
    int st = -1;
    waitpid(child, &st, 0);
    v = -1;
    rc = gpio_level(&v);
    snprintf(name, sizeof name, "gpio_%s_released_at_exit", high ? "high" : "low");
    result(name, child > 0 && WIFEXITED(st) && WEXITSTATUS(st) == 0 && rc == 0 && v == !high,
           "child exit 0x%x, line %d level %d (rc %d)", st, GPIO_LINE, v, rc);
}

/* rs485_checks set FLAGS BEFORE AFTER      the board's config (raw ioctl)
 * rs485_checks expect FLAGS BEFORE AFTER NAME   RESULT: is it that now? */
static int ctl(int argc, char **argv)
{
    if (argc < 5)
        return 2;
    struct serial_rs485 want;
    memset(&want, 0, sizeof want);
    want.flags = (uint32_t)strtoul(argv[2], NULL, 0);
    want.delay_rts_before_send = (uint32_t)strtoul(argv[3], NULL, 0);
    want.delay_rts_after_send = (uint32_t)strtoul(argv[4], NULL, 0);
    if (strcmp(argv[1], "set") == 0) {
        struct serial_rs485 got = board(want.flags, want.delay_rts_before_send,
                                        want.delay_rts_after_send);
        printf("board set to %s\n", fmt_rs(&got));
        return 0;
    }
    struct serial_rs485 now;
    int rc = raw_get(&now);
    result(argc > 5 ? argv[5] : "expect", rc == 0 && now.flags == want.flags &&
           now.delay_rts_before_send == want.delay_rts_before_send &&
           now.delay_rts_after_send == want.delay_rts_after_send,
           "expected %s, port has %s", fmt_rs(&want), fmt_rs(&now));
    return failures != 0;
}

int main(int argc, char **argv)
{
    if (argc > 1 && (strcmp(argv[1], "set") == 0 || strcmp(argv[1], "expect") == 0))
        return ctl(argc, argv);
    if (argc > 1)
        dev = argv[1];
    struct serial_rs485 off;
    memset(&off, 0, sizeof off);
    struct serial_rs485 board_low = off;   /* the board: active low, 7/9 ms, ON */
    board_low.flags = SER_RS485_ENABLED | SER_RS485_RTS_AFTER_SEND;
    board_low.delay_rts_before_send = 7;
    board_low.delay_rts_after_send = 9;

    check_kernel_cleaning();
    check_kernel_readback();
    check_kernel_keeps_board(FAP_RS485_KERNEL, "kernel_keeps_board_config");
    check_kernel_keeps_board(FAP_RS485_AUTO, "auto_keeps_board_config");
    check_reopen_restore();
    check_auto();
    trace_check("kernel_high", FAP_RS485_KERNEL, 1, 5, 8, off);
    trace_check("kernel_low", FAP_RS485_KERNEL, 0, 5, 8, off);
    trace_check("soft_high", FAP_RS485_SOFT_RTS, 1, 5, 8, off);
    trace_check("soft_low", FAP_RS485_SOFT_RTS, 0, 5, 8, off);
    trace_check("soft_over_kernel", FAP_RS485_SOFT_RTS, 1, 4, 6, board_low);
    /* GPIO DE/RE on the PL061, timed against the PL011's data bytes */
    gpio_prime();
    trace_check("gpio_high", FAP_RS485_GPIO, 1, 3, 5, off);
    trace_check("gpio_low", FAP_RS485_GPIO, 0, 3, 5, off);
    trace_check("gpio_high_nodelay", FAP_RS485_GPIO, 1, 0, 0, off);
    trace_check("gpio_low_nodelay", FAP_RS485_GPIO, 0, 0, 0, off);
    gpio_released(1);
    gpio_released(0);
    printf("CHECKS-DONE failures=%d\n", failures);
    fflush(stdout);
    return failures != 0;
}
