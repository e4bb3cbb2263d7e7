/* bench_vbus.c - how fast the virtual RS-485 bus relays, and how precisely
 * it paces. Not a test: prints tables.
 *
 *   bench_vbus [--quick]
 *
 * 1. Unpaced throughput: one node writes frames of 8, 64 and 4096 bytes as
 *    fast as it can, every other node reads; 2 and 4 ports. The writer stays
 *    at most WINDOW bytes ahead of the slowest reader, so nothing overflows
 *    and every frame is counted only once all receivers have it.
 *    Compared with: a bare kernel pty pair (no relay: the ceiling), socat
 *    relaying two ptys (the usual tool, 2 ports only, if installed), and the
 *    fastest RS-485 wires (115200 baud and 10 Mbaud at 10 bits per byte).
 * 2. Paced: a 100-byte frame at 9600 and 115200 baud, write to last byte
 *    read, against the ideal 100 * 10 / baud; and the lateness of every
 *    byte against its ideal arrival (write time + (i+1) char times).
 */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "fap_vbus.h"

#define WINDOW (16 * 1024)
#define MAX_RX 8

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int open_raw(const char *path, int nonblock)
{
    int fd = open(path, O_RDWR | O_NOCTTY | O_CLOEXEC | (nonblock ? O_NONBLOCK : 0));
    if (fd < 0)
        return -1;
    struct termios t;
    if (tcgetattr(fd, &t) == 0) {
        cfmakeraw(&t);
        tcsetattr(fd, TCSANOW, &t);
    }
    tcflush(fd, TCIOFLUSH);
    return fd;
}

/* ---- unpaced throughput ------------------------------------------------- */

typedef struct flow {
    int tx_fd;
    int rx_fd[MAX_RX];
    int n_rx;
    size_t frame, frames;
    _Atomic size_t received[MAX_RX];
    pthread_mutex_t mu;
    pthread_cond_t cv;
    atomic_int writer_waiting;
    atomic_int failed;
} flow;

typedef struct rx_arg {
    flow *f;
    int i;
} rx_arg;

static size_t slowest(flow *f)
{
    size_t m = (size_t)-1;
    for (int i = 0; i < f->n_rx; i++) {
        size_t r = atomic_load(&f->received[i]);
        if (r < m)
            m = r;
    }
    return m;
}

static void *rx_main(void *p)
{
    rx_arg *a = p;
    flow *f = a->f;
    size_t want = f->frame * f->frames;
    static __thread unsigned char buf[65536];
    size_t got = 0;
    while (got < want) {
        struct pollfd pfd = { .fd = f->rx_fd[a->i], .events = POLLIN };
        if (poll(&pfd, 1, 3000) <= 0) {
            atomic_store(&f->failed, 1);   /* data lost: the window failed */
            break;
        }
        ssize_t r = read(f->rx_fd[a->i], buf, sizeof buf);
        if (r <= 0)
            continue;
        got += (size_t)r;
        atomic_store(&f->received[a->i], got);
        if (atomic_load(&f->writer_waiting)) {
            pthread_mutex_lock(&f->mu);
            pthread_cond_signal(&f->cv);
            pthread_mutex_unlock(&f->mu);
        }
    }
    pthread_mutex_lock(&f->mu);
    pthread_cond_signal(&f->cv);
    pthread_mutex_unlock(&f->mu);
    return NULL;
}

/* frames/s for the given pty endpoints; <0 if data was lost */
static double run_flow(int tx, const int *rx, int n_rx, size_t frame, size_t frames)
{
    flow f;
    memset(&f, 0, sizeof f);
    f.tx_fd = tx;
    f.n_rx = n_rx;
    memcpy(f.rx_fd, rx, sizeof(int) * (size_t)n_rx);
    f.frame = frame;
    f.frames = frames;
    pthread_mutex_init(&f.mu, NULL);
    pthread_cond_init(&f.cv, NULL);
    pthread_t th[MAX_RX];
    rx_arg args[MAX_RX];
    unsigned char *buf = malloc(frame);
    memset(buf, 0x5a, frame);
    double t0 = now_s();
    for (int i = 0; i < n_rx; i++) {
        args[i] = (rx_arg){ &f, i };
        pthread_create(&th[i], NULL, rx_main, &args[i]);
    }
    size_t sent = 0;
    for (size_t k = 0; k < frames && !atomic_load(&f.failed); k++) {
        while (sent - slowest(&f) > WINDOW && !atomic_load(&f.failed)) {
            pthread_mutex_lock(&f.mu);
            atomic_store(&f.writer_waiting, 1);
            if (sent - slowest(&f) > WINDOW) {
                struct timespec ts;
                clock_gettime(CLOCK_REALTIME, &ts);
                ts.tv_nsec += 10 * 1000000;
                if (ts.tv_nsec >= 1000000000) {
                    ts.tv_sec++;
                    ts.tv_nsec -= 1000000000;
                }
                pthread_cond_timedwait(&f.cv, &f.mu, &ts);
            }
            atomic_store(&f.writer_waiting, 0);
            pthread_mutex_unlock(&f.mu);
        }
        size_t off = 0;
        while (off < frame) {
            ssize_t w = write(tx, buf + off, frame - off);
            if (w > 0)
                off += (size_t)w;
            else if (errno != EINTR && errno != EAGAIN) {
                atomic_store(&f.failed, 1);
                break;
            }
        }
        sent += frame;
    }
    for (int i = 0; i < n_rx; i++)
        pthread_join(th[i], NULL);
    double dt = now_s() - t0;
    free(buf);
    pthread_cond_destroy(&f.cv);
    pthread_mutex_destroy(&f.mu);
    return atomic_load(&f.failed) ? -1.0 : (double)frames / dt;
}

static size_t frames_for(size_t frame, int quick)
{
    size_t bytes = frame <= 8 ? (1u << 20) : frame <= 64 ? (4u << 20) : (32u << 20);
    if (quick)
        bytes /= 8;
    return bytes / frame;
}

static void print_row(const char *what, int ports, size_t frame, double fps)
{
    if (fps < 0) {
        printf("%-26s %5d %7zu %12s %10s %12s %12s\n", what, ports, frame, "LOST", "-", "-", "-");
        return;
    }
    double mbs = fps * (double)frame / 1e6;
    /* RS-485 wire carries baud/10 bytes per second */
    printf("%-26s %5d %7zu %12.0f %10.2f %11.0fx %11.1fx\n", what, ports, frame, fps, mbs,
           mbs * 1e6 / 11520.0, mbs * 1e6 / 1e6);
}

static void bench_vbus_flow(int ports, size_t frame, int quick)
{
    fap_vbus_options o;
    fap_vbus_options_init(&o);
    o.n_ports = (unsigned)ports;
    fap_vbus *bus;
    if (fap_vbus_open(&bus, &o) != 0) {
        printf("fap_vbus_open failed\n");
        return;
    }
    int fd[MAX_RX + 1];
    for (int i = 0; i < ports; i++)
        fd[i] = open_raw(fap_vbus_port_path(bus, (unsigned)i), 0);
    double fps = run_flow(fd[0], fd + 1, ports - 1, frame, frames_for(frame, quick));
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    for (int i = 0; i < ports; i++)
        close(fd[i]);
    fap_vbus_close(bus);
    print_row("fap vbus (relay thread)", ports, frame, st.overflow ? -1.0 : fps);
}

static void bench_pty_pair(size_t frame, int quick)
{
    int m = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
    char name[64];
    if (m < 0 || grantpt(m) || unlockpt(m) || ptsname_r(m, name, sizeof name))
        return;
    int s = open_raw(name, 0);
    struct termios t;
    tcgetattr(m, &t);
    cfmakeraw(&t);
    tcsetattr(m, TCSANOW, &t);
    double fps = run_flow(s, &m, 1, frame, frames_for(frame, quick));
    close(s);
    close(m);
    print_row("kernel pty pair, no relay", 2, frame, fps);
}

/* socat relaying two ptys: the tool people use for a 2-node virtual link */
static void bench_socat(size_t frame, int quick)
{
    char dir[] = "/tmp/bench-vbus-socat-XXXXXX";
    if (!mkdtemp(dir))
        return;
    char a[128], b[128], arg_a[200], arg_b[200];
    snprintf(a, sizeof a, "%s/a", dir);
    snprintf(b, sizeof b, "%s/b", dir);
    snprintf(arg_a, sizeof arg_a, "PTY,raw,echo=0,link=%s", a);
    snprintf(arg_b, sizeof arg_b, "PTY,raw,echo=0,link=%s", b);
    pid_t pid = fork();
    if (pid == 0) {
        int devnull = open("/dev/null", O_WRONLY);
        dup2(devnull, 2);
        execlp("socat", "socat", "-b65536", arg_a, arg_b, (char *)NULL);
        _exit(127);
    }
    struct stat st;
    double t0 = now_s();
    while ((stat(a, &st) != 0 || stat(b, &st) != 0) && now_s() - t0 < 3.0) {
        int status;
        if (waitpid(pid, &status, WNOHANG) == pid) {
            printf("%-26s %5d %7zu   (socat not installed: apt-get install socat)\n",
                   "socat PTY<->PTY", 2, frame);
            rmdir(dir);
            return;
        }
        poll(NULL, 0, 5);   /* waiting for another process to create files */
    }
    int fa = open_raw(a, 0), fb = open_raw(b, 0);
    double fps = (fa >= 0 && fb >= 0) ? run_flow(fa, &fb, 1, frame, frames_for(frame, quick))
                                      : -1.0;
    close(fa);
    close(fb);
    kill(pid, SIGTERM);
    waitpid(pid, NULL, 0);
    unlink(a);
    unlink(b);
    rmdir(dir);
    print_row("socat PTY<->PTY", 2, frame, fps);
}

/* ---- paced ---------------------------------------------------------------- */

static int cmp_double(const void *x, const void *y)
{
    double a = *(const double *)x, b = *(const double *)y;
    return (a > b) - (a < b);
}

static void bench_paced(unsigned baud, int frames)
{
    fap_vbus_options o;
    fap_vbus_options_init(&o);
    o.baud = baud;
    fap_vbus *bus;
    if (fap_vbus_open(&bus, &o) != 0)
        return;
    int tx = open_raw(fap_vbus_port_path(bus, 0), 0);
    int rx = open_raw(fap_vbus_port_path(bus, 1), 0);
    const double T = 10.0 / baud;
    double *late = malloc(sizeof(double) * 100 * (size_t)frames);
    double ft_sum = 0, ft_min = 1e9, ft_max = 0;
    size_t nl = 0;
    unsigned char frame[100], buf[100];
    memset(frame, 0xa5, sizeof frame);
    for (int k = 0; k < frames; k++) {
        double t0 = now_s();
        if (write(tx, frame, 100) != 100)
            break;
        size_t got = 0;
        while (got < 100) {
            struct pollfd pfd = { .fd = rx, .events = POLLIN };
            if (poll(&pfd, 1, 3000) <= 0)
                break;
            ssize_t r = read(rx, buf, 100 - got);
            double t = now_s();
            for (ssize_t i = 0; i < r; i++)
                late[nl++] = t - (t0 + (double)(got + (size_t)i + 1) * T);
            if (r > 0)
                got += (size_t)r;
        }
        double ft = now_s() - t0;
        ft_sum += ft;
        ft_min = ft < ft_min ? ft : ft_min;
        ft_max = ft > ft_max ? ft : ft_max;
    }
    qsort(late, nl, sizeof *late, cmp_double);
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    printf("%7u %7d %10.2f %9.2f %9.2f %9.2f   %8.1f %8.1f %8.1f   %8.1f %8.1f\n", baud,
           frames, 100 * T * 1e3, ft_sum / frames * 1e3, ft_min * 1e3, ft_max * 1e3,
           late[nl / 2] * 1e6, late[nl * 99 / 100] * 1e6, late[nl - 1] * 1e6,
           st.paced_bytes ? (double)st.pace_late_sum_ns / (double)st.paced_bytes / 1e3 : 0.0,
           (double)st.pace_late_max_ns / 1e3);
    free(late);
    close(tx);
    close(rx);
    fap_vbus_close(bus);
}

int main(int argc, char **argv)
{
    int quick = argc > 1 && strcmp(argv[1], "--quick") == 0;
    signal(SIGPIPE, SIG_IGN);
    /* the machine's load changes the jitter: say what it was */
    char load[64] = "?";
    FILE *lf = fopen("/proc/loadavg", "r");
    if (lf) {
        if (!fgets(load, sizeof load, lf))
            strcpy(load, "?\n");
        fclose(lf);
    }
    printf("bench_vbus%s, %ld CPUs, load average %s", quick ? " --quick" : "",
           sysconf(_SC_NPROCESSORS_ONLN), load);
    printf("== unpaced relay throughput (writer <= %d KiB ahead of the slowest reader)\n",
           WINDOW / 1024);
    printf("%-26s %5s %7s %12s %10s %12s %12s\n", "", "ports", "write B", "frames/s",
           "MB/s/rx", "vs 115200bd", "vs 10Mbaud");
    const size_t sizes[] = { 8, 64, 4096 };
    for (int s = 0; s < 3; s++) {
        bench_pty_pair(sizes[s], quick);
        bench_socat(sizes[s], quick);
        bench_vbus_flow(2, sizes[s], quick);
        bench_vbus_flow(4, sizes[s], quick);
    }
    printf("\n== paced: 100-byte frame, write -> last byte read; byte lateness vs ideal\n"
           "   (reader: when the reading node got each byte; relay: when the pacer handed\n"
           "    it over, from fap_vbus_stats)\n");
    printf("%7s %7s %10s %9s %9s %9s   %8s %8s %8s   %8s %8s\n", "baud", "frames",
           "ideal ms", "mean ms", "min ms", "max ms", "rd p50us", "rd p99us", "rd maxus",
           "relay mean", "relay max");
    bench_paced(9600, quick ? 5 : 20);
    bench_paced(115200, quick ? 20 : 100);
    return 0;
}
