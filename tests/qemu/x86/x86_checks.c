/* x86_checks.c - runs inside the x86_64 QEMU guest on the 8250 (ttyS0 ISA,
 * ttyS2 PCI) and ftdi_sio (ttyUSB0) drivers. Subcommands, one job each,
 * called by init.sh in turn (never two on different ports at once: QEMU's
 * serial trace does not say which UART a register write went to):
 *   info DEV LABEL        RS-485 ioctls, the probe's verdict, AUTO's choice,
 *                         the termios a soft-RTS open and close leaves
 *   trace DEV LABEL HIGH BEFORE_MS AFTER_MS
 *                         soft RTS: open, idle, send "<LABEL>", idle, close,
 *                         idle; TRACE line for the host (run.py judges the
 *                         RTS edges and the level left after close)
 *   busy DEV LABEL HIGH   a child holds the port (soft RTS); the probe on
 *                         it must answer -EBUSY without opening it
 *   check DEV LABEL       fap_port_check_direction while the host echoes
 *   latency DEV LABEL     FTDI latency_timer 1 ms while open, restored
 *   drain DEV LABEL N     soft RTS, one N-byte write while the host stalls
 *                         its side: how long the write (tcdrain) took
 * Lines: RESULT <name> PASS|FAIL <detail>, TRACE <name> k=v ... */
#include <errno.h>
#include <fcntl.h>
#include <linux/serial.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "fap_port.h"

static int failures;

static void result(const char *label, const char *name, int ok, const char *fmt, ...)
{
    char detail[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    printf("RESULT %s_%s %s %s\n", label, name, ok ? "PASS" : "FAIL", detail);
    fflush(stdout);
    failures += !ok;
}

static void msleep(int ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    while (nanosleep(&ts, &ts) < 0 && errno == EINTR) {}
}

static fap_port *open_soft(const char *dev, int high, unsigned before_ms, unsigned after_ms)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = FAP_RS485_SOFT_RTS;
    o.rts_active_high = high;
    o.delay_before_send_us = before_ms * 1000u;
    o.delay_after_send_us = after_ms * 1000u;
    fap_port *p = NULL;
    int err = fap_port_open(&p, dev, &o);
    if (err)
        result("soft", "open", 0, "%s: %s", dev, fap_port_strerror(err));
    return p;
}

static int raw_termios(const char *dev, struct termios *t)
{
    int fd = open(dev, O_RDWR | O_NOCTTY | O_NONBLOCK);
    int rc = fd >= 0 && tcgetattr(fd, t) == 0 ? 0 : -1;
    if (fd >= 0)
        close(fd);
    return rc;
}

/* A soft-RTS open and close gives the termios back (the speed here), with
 * HUPCL cleared so that the close leaves RTS where the port put it. */
static void soft_restore(const char *dev, const char *label)
{
    struct termios before, after;
    if (raw_termios(dev, &before) < 0)
        return;
    fap_port *p = open_soft(dev, 1, 0, 0);
    if (!p)
        return;
    fap_port_close(p);
    int rc = raw_termios(dev, &after);
    result(label, "soft_close_restores_termios", rc == 0 &&
           cfgetospeed(&after) == cfgetospeed(&before) && !(after.c_cflag & HUPCL) &&
           (before.c_cflag & HUPCL), "speed code %o -> %o, HUPCL %d -> %d",
           (unsigned)cfgetospeed(&before), (unsigned)cfgetospeed(&after),
           !!(before.c_cflag & HUPCL), !!(after.c_cflag & HUPCL));
}

/* What the driver answers, what the probe says, what AUTO picks. */
static void info(const char *dev, const char *label, int is_uart)
{
    int fd = open(dev, O_RDWR | O_NOCTTY | O_NONBLOCK);
    struct serial_rs485 r;
    memset(&r, 0, sizeof r);
    int g = fd >= 0 && ioctl(fd, TIOCGRS485, &r) == 0 ? 0 : errno;
    struct serial_rs485 w = r;
    int s = fd >= 0 && ioctl(fd, TIOCSRS485, &w) == 0 ? 0 : errno;
    if (fd >= 0)
        close(fd);
    /* 8250: reports {0}, refuses to set; ftdi_sio: no RS-485 at all */
    result(label, "rs485_ioctls", is_uart ? g == 0 && r.flags == 0 && s == ENOTTY
                                          : g == ENOTTY && s == ENOTTY,
           "TIOCGRS485 %s flags 0x%x, TIOCSRS485 %s", g ? strerror(g) : "ok", r.flags,
           s ? strerror(s) : "ok");
    unsigned baud = 0;
    int pr = fap_port_probe(dev, &baud, NULL, NULL, NULL);
    result(label, "probe_verdict", pr == (is_uart ? 1 : -ENOTTY),
           "fap_port_probe %d (%s), baud %u", pr, pr == 1 ? "read-only" : fap_port_strerror(pr), baud);
    fap_port_options o;
    fap_port_options_init(&o);
    fap_port *p = NULL;
    int err = fap_port_open(&p, dev, &o);
    result(label, "auto_picks_none", err == 0 && fap_port_mode(p) == FAP_RS485_NONE &&
           fap_port_auto_errno(p) == ENOTTY, "open %d, mode %s, auto_errno %d (%s)", err,
           err ? "-" : fap_rs485_mode_name(fap_port_mode(p)), err ? 0 : fap_port_auto_errno(p),
           err ? "-" : strerror(fap_port_auto_errno(p)));
    fap_port_close(p);
    soft_restore(dev, label);
}

static void trace(const char *dev, const char *label, int high, unsigned before_ms,
                  unsigned after_ms)
{
    fap_port *p = open_soft(dev, high, before_ms, after_ms);
    if (!p)
        return;
    msleep(100);   /* idle after open: the receive level must hold */
    char payload[48];
    int n = snprintf(payload, sizeof payload, "<%s>", label);
    ssize_t w = fap_port_write(p, payload, (size_t)n);
    msleep(100);
    fap_port_close(p);
    msleep(150);   /* the level the close left, before the next open */
    result(label, "write", w == n, "fap_port_write %zd of %d", w, n);
    printf("TRACE %s high=%d before_ms=%u after_ms=%u payload=", label, high, before_ms, after_ms);
    for (int i = 0; i < n; i++)
        printf("%02x", (unsigned char)payload[i]);
    printf("\n");
    fflush(stdout);
}

/* Another process (a child) holds the port with soft RTS; the probe must
 * not open it. HELD / PROBE-END bracket the window in which the host
 * checks that no RTS write reached the UART. */
static void busy(const char *dev, const char *label, int high)
{
    int go[2], stop[2];
    if (pipe(go) < 0 || pipe(stop) < 0)
        return;
    fflush(stdout);
    pid_t child = fork();
    if (child == 0) {
        close(go[0]);
        close(stop[1]);
        fap_port *p = open_soft(dev, high, 0, 0);
        char c = p ? 'y' : 'n', buf[8];
        if (write(go[1], &c, 1) < 0) {}
        while (read(stop[0], buf, sizeof buf) > 0) {}   /* until the parent is done */
        fap_port_close(p);
        _exit(p ? 0 : 1);
    }
    close(go[1]);
    close(stop[0]);
    char c = 'n';
    if (child < 0 || read(go[0], &c, 1) != 1 || c != 'y') {
        result(label, "probe_busy", 0, "the holder could not open %s", dev);
        return;
    }
    msleep(50);
    printf("HELD %s\n", label);
    fflush(stdout);
    msleep(50);
    int pr = fap_port_probe(dev, NULL, NULL, NULL, NULL);
    msleep(50);
    printf("PROBE-END %s\n", label);
    fflush(stdout);
    msleep(50);
    close(stop[1]);
    close(go[0]);
    int st = 0;
    waitpid(child, &st, 0);
    result(label, "probe_busy", pr == -EBUSY, "fap_port_probe on a port held by pid %d: %d (%s)",
           (int)child, pr, fap_port_strerror(pr));
}

static int64_t now_ms(void)
{
    return fap_port_now_ns() / 1000000;
}

/* The host stalls its end of the line: the UART cannot send, and tcdrain
 * (inside the soft-RTS write) must wait for the last byte. */
static void drain(const char *dev, const char *label, size_t n)
{
    fap_port *p = open_soft(dev, 1, 0, 0);
    if (!p)
        return;
    char *buf = malloc(n);
    if (!buf)
        return;
    for (size_t i = 0; i < n; i++)
        buf[i] = (char)('a' + i % 26);
    memcpy(buf + n - 6, "<END>\n", 6);
    printf("DRAIN-START\n");
    fflush(stdout);
    int64_t t0 = now_ms();
    ssize_t w = fap_port_write(p, buf, n);
    int64_t took = now_ms() - t0;
    fap_port_close(p);
    free(buf);
    printf("DRAIN-DONE ms=%lld\n", (long long)took);
    result(label, "drain_write", w == (ssize_t)n, "fap_port_write %zd of %zu in %lld ms", w, n,
           (long long)took);
}

static int latency_ms(const char *dev, int set)
{
    char file[128];
    snprintf(file, sizeof file, "/sys/class/tty/%s/device/latency_timer", strrchr(dev, '/') + 1);
    FILE *f = fopen(file, set >= 0 ? "w" : "r");
    if (f && set >= 0) {
        fprintf(f, "%d\n", set);
        fclose(f);
        return set;
    }
    int v = -1;
    if (f) {
        if (fscanf(f, "%d", &v) != 1)
            v = -1;
        fclose(f);
    }
    return v;
}

/* FTDI: latency_timer at 1 ms while a soft-RTS port is open, the old
 * value back at close. QEMU's model starts at 0: set a real chip's 16 ms. */
static void latency(const char *dev, const char *label)
{
    int before = latency_ms(dev, 16) == 16 ? latency_ms(dev, -1) : -1;
    fap_port *p = open_soft(dev, 1, 0, 0);
    if (!p)
        return;
    int during = latency_ms(dev, -1);
    fap_port_close(p);
    int after = latency_ms(dev, -1);
    result(label, "latency_timer_low_while_open", before == 16 && during == 1 && after == before,
           "latency_timer %d ms, %d while open, %d after close", before, during, after);
}

/* fap ports --check's measurement (fap_port_check_direction) with soft
 * RTS, while the host end echoes every byte (a transceiver with RX during
 * TX). The host relays the echo through the pty, so its latency is in the
 * margin: the check is that a release time is reported for every round. */
static void direction(const char *dev, const char *label)
{
    fap_port *p = open_soft(dev, 1, 0, 0);
    if (!p)
        return;
    printf("CHECK-START %s\n", label);
    fflush(stdout);
    char go[16];
    if (!fgets(go, sizeof go, stdin)) {}   /* the host echoes from now on */
    static const char pattern[] = "UUUUUUUUUUUUUUUUUUUUUUUUUUUUUU\x0f\xf0";
    fap_port_check c;
    int rc = fap_port_check_direction(p, pattern, sizeof pattern - 1, 5, 1000, &c);
    fap_port_close(p);
    printf("CHECK-END %s\n", label);
    char margins[160] = "";
    for (unsigned i = 0, o = 0; i < c.echoed && o < sizeof margins - 16; i++)
        o += (unsigned)snprintf(margins + o, sizeof margins - o, " %+lld", (long long)(c.margin_ns[i] / 1000));
    result(label, "direction_check", rc == 0 && c.rounds == 5 && c.echoed == 5 && c.collisions == 0,
           "rc %d, %u of %u rounds echoed, %llu collisions, release - last echo (us):%s", rc,
           c.echoed, c.rounds, (unsigned long long)c.collisions, margins);
}

int main(int argc, char **argv)
{
    if (argc < 3)
        return 2;
    const char *cmd = argv[1], *dev = argv[2];
    const char *label = argc > 3 ? argv[3] : "x";
    if (strcmp(cmd, "info") == 0)
        info(dev, label, strstr(dev, "ttyS") != NULL);
    else if (strcmp(cmd, "trace") == 0 && argc > 6)
        trace(dev, label, atoi(argv[4]), (unsigned)atoi(argv[5]), (unsigned)atoi(argv[6]));
    else if (strcmp(cmd, "check") == 0)
        direction(dev, label);
    else if (strcmp(cmd, "latency") == 0)
        latency(dev, label);
    else if (strcmp(cmd, "busy") == 0 && argc > 4) {
        busy(dev, label, atoi(argv[4]));
    } else if (strcmp(cmd, "drain") == 0 && argc > 4)
        drain(dev, label, (size_t)atol(argv[4]));
    else
        return 2;
    return failures != 0;
}
