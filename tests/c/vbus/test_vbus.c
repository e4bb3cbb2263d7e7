/* test_vbus.c - the virtual RS-485 bus, driven through real ptys. */
#include <errno.h>
#include <limits.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <sys/wait.h>

#include "fap_vbus.h"
#include "unit.h"
#include "vbus_test_io.h"

#define WAIT_MS 3000   /* generous deadline for data that must arrive */

static fap_vbus *open_bus(unsigned n, unsigned baud, int echo, uint64_t seed,
                          const char *capture)
{
    fap_vbus_options o;
    fap_vbus_options_init(&o);
    o.n_ports = n;
    o.baud = baud;
    o.echo = echo;
    o.seed = seed;
    o.capture_path = capture;
    fap_vbus *bus = NULL;
    int r = fap_vbus_open(&bus, &o);
    CHECK_EQ(r, 0);
    return r == 0 ? bus : NULL;
}

/* Open every port of the bus as a node would. */
static void open_nodes(fap_vbus *bus, int *fd)
{
    for (unsigned i = 0; i < fap_vbus_port_count(bus); i++) {
        fd[i] = vt_open(fap_vbus_port_path(bus, i));
        CHECK(fd[i] >= 0);
    }
}

static void close_nodes(int *fd, unsigned n)
{
    for (unsigned i = 0; i < n; i++)
        if (fd[i] >= 0)
            close(fd[i]);
}

static void test_options_and_paths(void)
{
    fap_vbus_options o;
    fap_vbus_options_init(&o);
    CHECK_EQ(o.n_ports, 2);
    CHECK_EQ(o.baud, 0);
    fap_vbus *bus = (fap_vbus *)1;
    o.n_ports = 1;
    CHECK_EQ(fap_vbus_open(&bus, &o), -EINVAL);
    o.n_ports = FAP_VBUS_MAX_PORTS + 1;
    CHECK_EQ(fap_vbus_open(&bus, &o), -EINVAL);
    CHECK_EQ(fap_vbus_open(NULL, &o), -EINVAL);
    o.n_ports = 2;
    o.link_dir = "/proc/not/a/dir";
    CHECK(fap_vbus_open(&bus, &o) < 0);
    fap_vbus_close(NULL);
    CHECK(fap_vbus_port_path(NULL, 0) == NULL);

    bus = open_bus(3, 0, 0, 0, NULL);
    REQUIRE(bus);
    CHECK_EQ(fap_vbus_port_count(bus), 3);
    CHECK(fap_vbus_port_path(bus, 3) == NULL);
    char dir[PATH_MAX] = "";
    for (unsigned i = 0; i < 3; i++) {
        const char *p = fap_vbus_port_path(bus, i);
        REQUIRE(p);
        char target[128];
        ssize_t n = readlink(p, target, sizeof target - 1);
        CHECK(n > 0);
        target[n > 0 ? n : 0] = '\0';
        CHECK(strncmp(target, "/dev/pts/", 9) == 0);
        char want[16];
        snprintf(want, sizeof want, "/port%u", i);
        CHECK(strstr(p, want) != NULL);
        snprintf(dir, sizeof dir, "%.*s", (int)(strrchr(p, '/') - p), p);
    }
    CHECK_EQ(fap_vbus_set_fault(bus, 3, 0.1, 0), -EINVAL);
    CHECK_EQ(fap_vbus_set_fault(bus, -2, 0.1, 0), -EINVAL);
    CHECK_EQ(fap_vbus_set_fault(bus, 0, 1.5, 0), -EINVAL);
    CHECK_EQ(fap_vbus_set_fault(bus, 0, 0, -0.1), -EINVAL);
    CHECK_EQ(fap_vbus_drop_next(bus, 3, 1), -EINVAL);
    CHECK_EQ(fap_vbus_corrupt_next(bus, 9, 1), -EINVAL);
    CHECK_EQ(fap_vbus_silence(bus, 3, 1), -EINVAL);
    CHECK_EQ(fap_vbus_disconnect(bus, 3, 1), -EINVAL);
    fap_vbus_close(bus);
    /* the private link dir and its symlinks are gone */
    struct stat st;
    CHECK(stat(dir, &st) != 0 && errno == ENOENT);
}

static void test_link_dir(void)
{
    char base[] = "/tmp/vbus-test-XXXXXX";
    char *made = mkdtemp(base);   /* REQUIRE evaluates twice: no side effects in it */
    REQUIRE(made != NULL);
    char dir[64];
    snprintf(dir, sizeof dir, "%s/links", base);
    fap_vbus_options o;
    fap_vbus_options_init(&o);
    o.n_ports = 2;
    o.link_dir = dir;
    fap_vbus *bus = NULL;
    int r = fap_vbus_open(&bus, &o);
    REQUIRE(r == 0);
    char want[128];
    snprintf(want, sizeof want, "%s/port1", dir);
    CHECK(strcmp(fap_vbus_port_path(bus, 1), want) == 0);
    int fd[2];
    open_nodes(bus, fd);
    CHECK_EQ(vt_write_all(fd[1], "xy", 2), 0);
    char got[2];
    CHECK_EQ(vt_read_n(fd[0], got, 2, WAIT_MS), 2);
    CHECK_MEM(got, "xy", 2);
    close_nodes(fd, 2);
    fap_vbus_close(bus);
    /* a regular file where a link would go is refused, not clobbered */
    char file[128];
    snprintf(file, sizeof file, "%s/port1", base);
    int f = open(file, O_WRONLY | O_CREAT | O_EXCL, 0644);
    CHECK(f >= 0);
    if (f >= 0)
        close(f);
    o.link_dir = base;
    bus = NULL;
    r = fap_vbus_open(&bus, &o);
    CHECK_EQ(r, -EEXIST);
    CHECK(bus == NULL);
    struct stat st;
    CHECK(lstat(file, &st) == 0 && S_ISREG(st.st_mode));
    snprintf(want, sizeof want, "%s/port0", base);
    CHECK(lstat(want, &st) != 0);   /* nothing left behind */
    CHECK(unlink(file) == 0);
    /* a stale link from an earlier run is replaced */
    CHECK(symlink("/dev/null", want) == 0);
    r = fap_vbus_open(&bus, &o);
    CHECK_EQ(r, 0);
    char target[64] = "";
    ssize_t tn = readlink(want, target, sizeof target - 1);
    CHECK(tn > 9 && strncmp(target, "/dev/pts/", 9) == 0);
    fap_vbus_close(bus);
    CHECK(lstat(want, &st) != 0);
    CHECK(rmdir(base) == 0);   /* links dirs are only removed when we made them */
}

static void test_broadcast_not_to_sender(void)
{
    fap_vbus *bus = open_bus(3, 0, 0, 0, NULL);
    REQUIRE(bus);
    int fd[3];
    open_nodes(bus, fd);
    const char msg[] = "hello bus";
    CHECK_EQ(vt_write_all(fd[0], msg, 9), 0);
    char got[16];
    CHECK_EQ(vt_read_n(fd[1], got, 9, WAIT_MS), 9);
    CHECK_MEM(got, msg, 9);
    CHECK_EQ(vt_read_n(fd[2], got, 9, WAIT_MS), 9);
    CHECK_MEM(got, msg, 9);
    /* A marker sent later by port 1 reaches port 0 first: nothing of its
     * own was queued before it (no echo). */
    CHECK_EQ(vt_write_all(fd[1], "M", 1), 0);
    CHECK_EQ(vt_read_n(fd[0], got, 1, WAIT_MS), 1);
    CHECK_EQ(got[0], 'M');
    CHECK_EQ(vt_read_n(fd[2], got, 1, WAIT_MS), 1);
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(st.bytes_in, 10);
    CHECK_EQ(st.bytes_out, 20);
    CHECK_EQ(st.collisions, 0);
    close_nodes(fd, 3);
    fap_vbus_close(bus);
}

static void test_echo(void)
{
    fap_vbus *bus = open_bus(2, 0, 1, 0, NULL);
    REQUIRE(bus);
    int fd[2];
    open_nodes(bus, fd);
    CHECK_EQ(vt_write_all(fd[0], "\x01\x02\x03", 3), 0);
    uint8_t got[3];
    CHECK_EQ(vt_read_n(fd[0], got, 3, WAIT_MS), 3);
    CHECK_MEM(got, "\x01\x02\x03", 3);
    CHECK_EQ(vt_read_n(fd[1], got, 3, WAIT_MS), 3);
    CHECK_MEM(got, "\x01\x02\x03", 3);
    close_nodes(fd, 2);
    fap_vbus_close(bus);
}

/* "Tests run a C program on a bus port": vbus_node (a separate executable)
 * sends a frame on port 0, we see it on ports 1 and 2 and answer. */
static void test_child_program(void)
{
    const char *node = getenv("VBUS_NODE");
    REQUIRE(node && *node);
    fap_vbus *bus = open_bus(3, 0, 0, 0, NULL);
    REQUIRE(bus);
    int fd[3] = { -1, -1, -1 };
    fd[1] = vt_open(fap_vbus_port_path(bus, 1));
    fd[2] = vt_open(fap_vbus_port_path(bus, 2));
    int out[2];
    int pr = pipe(out);
    REQUIRE(pr == 0);
    pid_t pid = fork();
    REQUIRE(pid >= 0);
    if (pid == 0) {
        dup2(out[1], 1);
        close(out[0]);
        execl(node, node, fap_vbus_port_path(bus, 0), "7e0102a5", "3", (char *)NULL);
        _exit(127);
    }
    close(out[1]);
    uint8_t got[4];
    CHECK_EQ(vt_read_n(fd[1], got, 4, WAIT_MS), 4);
    CHECK_MEM(got, "\x7e\x01\x02\xa5", 4);
    CHECK_EQ(vt_read_n(fd[2], got, 4, WAIT_MS), 4);
    CHECK_MEM(got, "\x7e\x01\x02\xa5", 4);
    CHECK_EQ(vt_write_all(fd[2], "\x10\x20\x30", 3), 0);
    char line[32] = "";
    ssize_t n = vt_read_n(out[0], line, 7, WAIT_MS);
    CHECK_EQ(n, 7);
    CHECK(strncmp(line, "102030\n", 7) == 0);
    int status = -1;
    CHECK_EQ(waitpid(pid, &status, 0), pid);
    CHECK(WIFEXITED(status) && WEXITSTATUS(status) == 0);
    close(out[0]);
    close_nodes(fd, 3);
    fap_vbus_close(bus);
}

static void test_paced_frame_time(void)
{
    fap_vbus *bus = open_bus(2, 9600, 0, 0, NULL);
    REQUIRE(bus);
    int fd[2];
    open_nodes(bus, fd);
    uint8_t frame[100], got[100];
    for (int i = 0; i < 100; i++)
        frame[i] = (uint8_t)(i * 7);
    long long t0 = vt_now_ms();
    CHECK_EQ(vt_write_all(fd[0], frame, 100), 0);
    CHECK_EQ(vt_read_n(fd[1], got, 100, 5000), 100);
    long long dt = vt_now_ms() - t0;
    CHECK_MEM(got, frame, 100);
    /* 100 bytes * 10 bits / 9600 baud = 104.2 ms; loose bounds only */
    CHECK(dt >= 95);
    CHECK(dt < 5000);
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(st.paced_bytes, 100);
    CHECK(st.pace_late_max_ns < 5000000000ull);   /* measured in the benchmark */
    CHECK(st.pace_late_sum_ns <= 100 * st.pace_late_max_ns);
    close_nodes(fd, 2);
    fap_vbus_close(bus);
}

static void test_collision(void)
{
    fap_vbus *bus = open_bus(3, 9600, 0, 0, NULL);
    REQUIRE(bus);
    int fd[3];
    open_nodes(bus, fd);
    uint8_t a[64], b[64], got[128];
    memset(a, 0x11, sizeof a);
    memset(b, 0x22, sizeof b);
    /* 64 bytes take ~67 ms at 9600 baud: the second write starts long
     * before the first transmission ends, even on a loaded machine */
    CHECK_EQ(vt_write_all(fd[0], a, 64), 0);
    CHECK_EQ(vt_write_all(fd[1], b, 64), 0);
    CHECK_EQ(vt_read_n(fd[2], got, 128, 5000), 128);
    int corrupted_a = 0, corrupted_b = 0, clean = 0;
    for (int i = 0; i < 128; i++) {
        if (got[i] == (uint8_t)~0x11)
            corrupted_a++;
        else if (got[i] == (uint8_t)~0x22)
            corrupted_b++;
        else if (got[i] == 0x11 || got[i] == 0x22)
            clean++;
    }
    CHECK(corrupted_a > 0);
    CHECK(corrupted_b > 0);
    CHECK_EQ(corrupted_a + corrupted_b + clean, 128);
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(st.collisions, 1);
    /* the senders hear each other's (corrupted) bytes too */
    CHECK_EQ(vt_read_n(fd[0], got, 64, 5000), 64);
    CHECK_EQ(vt_read_n(fd[1], got, 64, 5000), 64);
    close_nodes(fd, 3);
    fap_vbus_close(bus);
}

static void test_drop_and_corrupt_next(void)
{
    fap_vbus *bus = open_bus(2, 0, 0, 7, NULL);
    REQUIRE(bus);
    int fd[2];
    open_nodes(bus, fd);
    const uint8_t msg[10] = { 0, 1, 2, 3, 4, 5, 6, 7, 8, 9 };
    uint8_t got[10];
    CHECK_EQ(fap_vbus_drop_next(bus, 0, 3), 0);
    CHECK_EQ(vt_write_all(fd[0], msg, 10), 0);
    CHECK_EQ(vt_read_n(fd[1], got, 7, WAIT_MS), 7);
    CHECK_MEM(got, msg + 3, 7);
    /* only the next 3: the following bytes pass */
    CHECK_EQ(vt_write_all(fd[0], msg, 10), 0);
    CHECK_EQ(vt_read_n(fd[1], got, 10, WAIT_MS), 10);
    CHECK_MEM(got, msg, 10);

    CHECK_EQ(fap_vbus_corrupt_next(bus, 0, 2), 0);
    CHECK_EQ(vt_write_all(fd[0], msg, 10), 0);
    CHECK_EQ(vt_read_n(fd[1], got, 10, WAIT_MS), 10);
    for (int i = 0; i < 2; i++)
        CHECK_EQ(__builtin_popcount(got[i] ^ msg[i]), 1);   /* one bit flipped */
    CHECK_MEM(got + 2, msg + 2, 8);
    /* corruption is per sender: port 1's bytes pass untouched */
    CHECK_EQ(fap_vbus_corrupt_next(bus, 0, 5), 0);
    CHECK_EQ(vt_write_all(fd[1], msg, 10), 0);
    CHECK_EQ(vt_read_n(fd[0], got, 10, WAIT_MS), 10);
    CHECK_MEM(got, msg, 10);
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(st.dropped, 3);
    CHECK_EQ(st.bit_errors, 2);
    CHECK_EQ(st.bytes_in, 40);
    close_nodes(fd, 2);
    fap_vbus_close(bus);
}

static void test_silence(void)
{
    fap_vbus *bus = open_bus(3, 0, 0, 0, NULL);
    REQUIRE(bus);
    int fd[3];
    open_nodes(bus, fd);
    uint8_t got[4];
    CHECK_EQ(fap_vbus_silence(bus, 1, 60000), 0);
    /* port 1 hears nothing: port 2 got the byte, port 1 in the same
     * delivery did not */
    CHECK_EQ(vt_write_all(fd[0], "A", 1), 0);
    CHECK_EQ(vt_read_n(fd[2], got, 1, WAIT_MS), 1);
    CHECK_EQ(got[0], 'A');
    CHECK(!vt_pending(fd[1]));
    /* port 1's bytes vanish: port 2 sees C then D and nothing between */
    CHECK_EQ(vt_write_all(fd[1], "B", 1), 0);
    CHECK_EQ(vt_write_all(fd[0], "C", 1), 0);
    CHECK_EQ(vt_read_n(fd[2], got, 1, WAIT_MS), 1);
    CHECK_EQ(got[0], 'C');
    CHECK_EQ(vt_write_all(fd[0], "D", 1), 0);
    CHECK_EQ(vt_read_n(fd[2], got, 1, WAIT_MS), 1);
    CHECK_EQ(got[0], 'D');
    CHECK(!vt_pending(fd[1]));
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(st.dropped, 1);

    /* a timed silence ends by itself */
    CHECK_EQ(fap_vbus_silence(bus, 1, 100), 0);
    long long t0 = vt_now_ms();
    int heard = 0;
    while (!heard && vt_now_ms() - t0 < WAIT_MS) {
        CHECK_EQ(vt_write_all(fd[0], "E", 1), 0);
        CHECK_EQ(vt_read_n(fd[2], got, 1, WAIT_MS), 1);
        heard = vt_read_n(fd[1], got, 1, 20) == 1;
    }
    CHECK(heard);
    CHECK(vt_now_ms() - t0 >= 95);
    close_nodes(fd, 3);
    fap_vbus_close(bus);
}

static void test_disconnect(void)
{
    fap_vbus *bus = open_bus(2, 0, 0, 0, NULL);
    REQUIRE(bus);
    int fd[2];
    open_nodes(bus, fd);
    const char *path = fap_vbus_port_path(bus, 1);
    long long t0 = vt_now_ms();
    CHECK_EQ(fap_vbus_disconnect(bus, 1, 150), 0);
    /* the node's fd hangs up */
    struct pollfd pfd = { .fd = fd[1], .events = POLLIN };
    CHECK_EQ(poll(&pfd, 1, WAIT_MS), 1);
    CHECK(pfd.revents & POLLHUP);
    uint8_t c;
    CHECK_EQ(write(fd[1], "x", 1), -1);
    CHECK_EQ(errno, EIO);
    close(fd[1]);
    /* while disconnected the path opens nothing */
    int bad = vt_open(path);
    CHECK_EQ(bad, -ENOENT);
    if (bad >= 0)
        close(bad);
    /* bytes sent meanwhile reach nobody */
    CHECK_EQ(vt_write_all(fd[0], "lost", 4), 0);
    /* then the same path works again */
    fd[1] = -1;
    while (fd[1] < 0 && vt_now_ms() - t0 < WAIT_MS) {
        fd[1] = vt_open(path);
        if (fd[1] < 0)
            poll(NULL, 0, 5);   /* retry pacing of a reopen loop, as a node does */
    }
    REQUIRE(fd[1] >= 0);
    CHECK(vt_now_ms() - t0 >= 140);
    CHECK_EQ(vt_write_all(fd[0], "back", 4), 0);
    char got[4];
    CHECK_EQ(vt_read_n(fd[1], got, 4, WAIT_MS), 4);
    CHECK_MEM(got, "back", 4);
    CHECK_EQ(vt_write_all(fd[1], "ok", 2), 0);
    CHECK_EQ(vt_read_n(fd[0], got, 2, WAIT_MS), 2);
    CHECK_MEM(got, "ok", 2);
    (void)c;
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(st.disconnects, 1);
    close_nodes(fd, 2);
    fap_vbus_close(bus);
}

/* Send 256 bytes through a bus with bit errors; return the bytes received. */
static void ber_run(uint64_t seed, uint8_t *got, uint64_t *errors)
{
    fap_vbus *bus = open_bus(2, 0, 0, seed, NULL);
    if (!bus)
        return;
    int fd[2];
    open_nodes(bus, fd);
    CHECK_EQ(fap_vbus_set_fault(bus, -1, 0.2, 0.0), 0);
    uint8_t msg[256];
    memset(msg, 0x55, sizeof msg);
    /* several writes: chunking must not change the outcome */
    for (int i = 0; i < 256; i += 64)
        CHECK_EQ(vt_write_all(fd[0], msg + i, 64), 0);
    CHECK_EQ(vt_read_n(fd[1], got, 256, WAIT_MS), 256);
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    *errors = st.bit_errors;
    close_nodes(fd, 2);
    fap_vbus_close(bus);
}

static void test_seeded_bit_errors_reproduce(void)
{
    uint8_t a[256] = { 0 }, b[256] = { 0 }, c[256] = { 0 };
    uint64_t ea = 0, eb = 0, ec = 0;
    ber_run(42, a, &ea);
    ber_run(42, b, &eb);
    ber_run(43, c, &ec);
    CHECK(ea > 10 && ea < 120);   /* ~51 expected */
    CHECK_EQ(ea, eb);
    CHECK_MEM(a, b, 256);
    CHECK(memcmp(a, c, 256) != 0);
    int flipped = 0;
    for (int i = 0; i < 256; i++) {
        int bits = __builtin_popcount(a[i] ^ 0x55);
        CHECK(bits <= 1);
        flipped += bits;
    }
    CHECK_EQ(flipped, (int)ea);
}

static void test_drop_rate(void)
{
    fap_vbus *bus = open_bus(2, 0, 0, 5, NULL);
    REQUIRE(bus);
    int fd[2];
    open_nodes(bus, fd);
    CHECK_EQ(fap_vbus_set_fault(bus, 0, 0.0, 0.5), 0);
    uint8_t msg[200], got[200];
    memset(msg, 0xa5, sizeof msg);
    CHECK_EQ(vt_write_all(fd[0], msg, 200), 0);
    fap_vbus_stats st;
    /* the drops are counted when the relay reads: wait for the survivors */
    long long t0 = vt_now_ms();
    size_t total = 0;
    do {
        ssize_t n = vt_read_n(fd[1], got, sizeof got, 20);
        total += n > 0 ? (size_t)n : 0;
        fap_vbus_get_stats(bus, &st);
    } while (st.bytes_in < 200 && vt_now_ms() - t0 < WAIT_MS);
    size_t expect = 200 - (size_t)st.dropped;
    ssize_t n = vt_read_n(fd[1], got, expect - total, WAIT_MS);
    total += n > 0 ? (size_t)n : 0;
    CHECK_EQ(total, expect);
    CHECK(st.dropped > 50 && st.dropped < 150);
    CHECK_EQ(fap_vbus_set_fault(bus, 0, 0.0, 0.0), 0);
    CHECK_EQ(vt_write_all(fd[0], msg, 20), 0);
    CHECK_EQ(vt_read_n(fd[1], got, 20, WAIT_MS), 20);
    CHECK_MEM(got, msg, 20);
    close_nodes(fd, 2);
    fap_vbus_close(bus);
}

static void test_capture(void)
{
    char path[] = "/tmp/vbus-capture-XXXXXX";
    int tmp = mkstemp(path);
    REQUIRE(tmp >= 0);
    close(tmp);
    fap_vbus *bus = open_bus(3, 0, 0, 9, path);
    REQUIRE(bus);
    int fd[3];
    open_nodes(bus, fd);
    char got[3];
    CHECK_EQ(vt_write_all(fd[0], "abc", 3), 0);
    CHECK_EQ(vt_read_n(fd[2], got, 3, WAIT_MS), 3);
    CHECK_EQ(vt_write_all(fd[1], "\xff\x00", 2), 0);
    CHECK_EQ(vt_read_n(fd[2], got, 2, WAIT_MS), 2);
    CHECK_EQ(fap_vbus_drop_next(bus, 2, 1), 0);
    CHECK_EQ(vt_write_all(fd[2], "zq", 2), 0);
    CHECK_EQ(vt_read_n(fd[0], got, 1, WAIT_MS), 1);
    close_nodes(fd, 3);
    fap_vbus_close(bus);

    FILE *f = fopen(path, "r");
    REQUIRE(f);
    char line[512];
    int header = 0, l0 = 0, l1 = 0, l2 = 0, fault = 0, end = 0;
    while (fgets(line, sizeof line, f)) {
        unsigned long long t;
        unsigned port;
        char rest[400];
        if (strncmp(line, "# fap-vbus-capture 1 ports=3 baud=0 echo=0 seed=9", 49) == 0)
            header++;
        else if (strncmp(line, "# fault t=", 10) == 0 && strstr(line, "port=2 reason=drop_next n=1"))
            fault++;
        else if (strncmp(line, "# end t=", 8) == 0 && strstr(line, "bytes_in=7 "))
            end++;
        else if (sscanf(line, "%llu %u %399[^\n]", &t, &port, rest) == 3) {
            if (port == 0 && strcmp(rest, "61 62 63") == 0)
                l0++;
            else if (port == 1 && strcmp(rest, "ff 00") == 0)
                l1++;
            else if (port == 2 && strcmp(rest, "71") == 0)
                l2++;
        }
    }
    fclose(f);
    unlink(path);
    CHECK_EQ(header, 1);
    CHECK_EQ(l0, 1);
    CHECK_EQ(l1, 1);
    CHECK_EQ(l2, 1);
    CHECK_EQ(fault, 1);
    CHECK_EQ(end, 1);
}

/* A node that never reads must not stall the others: once its queue is
 * full its bytes are dropped and counted (stats.overflow). */
static void test_overflow_does_not_block(void)
{
    fap_vbus *bus = open_bus(3, 0, 0, 0, NULL);
    REQUIRE(bus);
    int fd[3];
    open_nodes(bus, fd);
    static uint8_t chunk[4096], got[4096];
    memset(chunk, 0x3c, sizeof chunk);
    const size_t total = 256 * 1024;   /* far beyond a pty buffer + the relay's queue */
    size_t sent = 0;
    while (sent < total) {
        /* port 2 keeps up, port 1 never reads */
        int w = vt_write_all(fd[0], chunk, sizeof chunk);
        REQUIRE(w == 0);
        sent += sizeof chunk;
        ssize_t n = vt_read_n(fd[2], got, sizeof got, WAIT_MS);
        REQUIRE(n == (ssize_t)sizeof got);
        CHECK_MEM(got, chunk, sizeof got);
    }
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK(st.overflow > 0);
    CHECK(st.overflow < total);
    /* now port 1 reads what was kept: kept + dropped == sent, exactly */
    size_t kept = 0;
    while (kept + st.overflow < total) {
        ssize_t n = vt_read_n(fd[1], got, sizeof got, 50);
        if (n <= 0 && kept + st.overflow < total) {
            fap_vbus_get_stats(bus, &st);
            if (n < 0)
                break;
            continue;
        }
        kept += (size_t)n;
    }
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(kept + st.overflow, total);
    CHECK(!vt_pending(fd[1]));
    close_nodes(fd, 3);
    fap_vbus_close(bus);
}

/* A port nobody has open receives nothing: a late opener (even one that
 * does not flush) starts clean, also after a previous node left bytes. */
static void test_late_opener_starts_clean(void)
{
    fap_vbus *bus = open_bus(3, 0, 0, 0, NULL);
    REQUIRE(bus);
    int fd[3] = { -1, -1, -1 };
    fd[0] = vt_open(fap_vbus_port_path(bus, 0));
    fd[2] = vt_open(fap_vbus_port_path(bus, 2));
    static uint8_t chunk[4096], got[4096];
    memset(chunk, 0x77, sizeof chunk);
    for (int i = 0; i < 32; i++) {   /* 128 KiB: more than a pty and our queue hold */
        CHECK_EQ(vt_write_all(fd[0], chunk, sizeof chunk), 0);
        CHECK_EQ(vt_read_n(fd[2], got, sizeof got, WAIT_MS), (ssize_t)sizeof got);
    }
    for (int round = 0; round < 2; round++) {
        /* no tcflush here on purpose */
        fd[1] = open(fap_vbus_port_path(bus, 1), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
        REQUIRE(fd[1] >= 0);
        CHECK_EQ(vt_write_all(fd[0], "fresh", 5), 0);
        CHECK_EQ(vt_read_n(fd[1], got, 5, WAIT_MS), 5);
        CHECK_MEM(got, "fresh", 5);
        /* leave unread bytes behind for the next opener */
        CHECK_EQ(vt_write_all(fd[0], "stale", 5), 0);
        CHECK_EQ(vt_read_n(fd[2], got, 10, WAIT_MS), 10);
        /* and leave the port exclusive, as a node that dies would */
        CHECK_EQ(ioctl(fd[1], TIOCEXCL), 0);
        close(fd[1]);
        /* once a later byte went round, the relay has seen the close */
        CHECK_EQ(vt_write_all(fd[0], "x", 1), 0);
        CHECK_EQ(vt_read_n(fd[2], got, 1, WAIT_MS), 1);
    }
    /* the relay cleared TIOCEXCL when the last node left (root may open an
     * exclusive tty anyway, so ask the flag itself) */
    fd[1] = vt_open(fap_vbus_port_path(bus, 1));
    CHECK(fd[1] >= 0);
    int excl = -1;
    CHECK_EQ(ioctl(fd[1], TIOCGEXCL, &excl), 0);
    CHECK_EQ(excl, 0);
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(st.overflow, 0);
    close_nodes(fd, 3);
    fap_vbus_close(bus);
}

/* Control calls from several threads while traffic flows (tsan checks the
 * locking); every setting is "no fault", so all data arrives intact. */
typedef struct hammer_arg {
    fap_vbus *bus;
    int calls;
    int errors;
} hammer_arg;

static void *hammer_main(void *p)
{
    hammer_arg *h = p;
    for (int i = 0; i < 2000; i++) {
        unsigned port = (unsigned)i % 3;
        fap_vbus_stats st;
        h->errors += fap_vbus_set_fault(h->bus, i % 2 ? -1 : (int)port, 0.0, 0.0) != 0;
        h->errors += fap_vbus_drop_next(h->bus, port, 0) != 0;
        h->errors += fap_vbus_corrupt_next(h->bus, port, 0) != 0;
        h->errors += fap_vbus_silence(h->bus, port, 0) != 0;
        fap_vbus_get_stats(h->bus, &st);
        h->calls += 5;
    }
    return NULL;
}

static void test_control_calls_from_many_threads(void)
{
    fap_vbus *bus = open_bus(3, 0, 0, 0, NULL);
    REQUIRE(bus);
    int fd[3];
    open_nodes(bus, fd);
    pthread_t th[3];
    hammer_arg h[3];
    for (int i = 0; i < 3; i++) {
        h[i] = (hammer_arg){ bus, 0, 0 };
        CHECK_EQ(pthread_create(&th[i], NULL, hammer_main, &h[i]), 0);
    }
    uint8_t msg[32], got[32];
    int intact = 0;
    for (int k = 0; k < 200; k++) {
        memset(msg, k, sizeof msg);
        CHECK_EQ(vt_write_all(fd[k % 3], msg, sizeof msg), 0);
        int to = (k + 1) % 3;
        intact += vt_read_n(fd[to], got, sizeof got, WAIT_MS) == (ssize_t)sizeof got &&
                  memcmp(got, msg, sizeof msg) == 0;
        CHECK_EQ(vt_read_n(fd[(k + 2) % 3], got, sizeof got, WAIT_MS), (ssize_t)sizeof got);
    }
    CHECK_EQ(intact, 200);
    for (int i = 0; i < 3; i++) {
        pthread_join(th[i], NULL);
        CHECK_EQ(h[i].calls, 10000);
        CHECK_EQ(h[i].errors, 0);
    }
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(st.bytes_in, 200 * 32);
    CHECK_EQ(st.dropped + st.bit_errors + st.overflow, 0);
    close_nodes(fd, 3);
    fap_vbus_close(bus);
}

/* The largest bus: port 63 is the last bit of the receiver masks. */
static void test_sixty_four_ports(void)
{
    fap_vbus *bus = open_bus(FAP_VBUS_MAX_PORTS, 0, 0, 0, NULL);
    REQUIRE(bus);
    int first = vt_open(fap_vbus_port_path(bus, 0));
    int last = vt_open(fap_vbus_port_path(bus, FAP_VBUS_MAX_PORTS - 1));
    CHECK(first >= 0 && last >= 0);
    uint8_t got[2];
    CHECK_EQ(vt_write_all(last, "hi", 2), 0);
    CHECK_EQ(vt_read_n(first, got, 2, WAIT_MS), 2);
    CHECK_MEM(got, "hi", 2);
    CHECK_EQ(vt_write_all(first, "yo", 2), 0);
    CHECK_EQ(vt_read_n(last, got, 2, WAIT_MS), 2);
    CHECK_MEM(got, "yo", 2);
    CHECK_EQ(fap_vbus_drop_next(bus, FAP_VBUS_MAX_PORTS - 1, 1), 0);
    CHECK_EQ(vt_write_all(last, "ab", 2), 0);
    CHECK_EQ(vt_read_n(first, got, 1, WAIT_MS), 1);
    CHECK_EQ(got[0], 'b');
    close(first);
    close(last);
    fap_vbus_close(bus);
}

/* A process that exits without fap_vbus_close leaves no links behind
 * (atexit); a fork child exiting leaves its parent's links alone. */
static void test_exit_without_close_removes_links(void)
{
    int pfd[2];
    int pr = pipe(pfd);
    REQUIRE(pr == 0);
    pid_t pid = fork();
    REQUIRE(pid >= 0);
    if (pid == 0) {
        fap_vbus_options o;
        fap_vbus_options_init(&o);
        o.n_ports = 3;
        fap_vbus *bus = NULL;
        if (fap_vbus_open(&bus, &o) != 0)
            _exit(3);
        const char *p = fap_vbus_port_path(bus, 0);
        char dir[256];
        snprintf(dir, sizeof dir, "%.*s", (int)(strrchr(p, '/') - p), p);
        if (write(pfd[1], dir, strlen(dir) + 1) < 0)
            _exit(4);
        exit(0);   /* no fap_vbus_close: atexit cleans up */
    }
    close(pfd[1]);
    char dir[256] = "";
    ssize_t n = vt_read_n(pfd[0], dir, sizeof dir - 1, WAIT_MS);
    close(pfd[0]);
    int status = -1;
    CHECK_EQ(waitpid(pid, &status, 0), pid);
    CHECK(WIFEXITED(status));
    CHECK(n > 0);
    struct stat st;
    CHECK(dir[0] == '/' && stat(dir, &st) != 0 && errno == ENOENT);

    fap_vbus *bus = open_bus(2, 0, 0, 0, NULL);
    REQUIRE(bus);
    pid = fork();
    REQUIRE(pid >= 0);
    if (pid == 0)
        exit(0);   /* runs atexit in the child: must not touch our links */
    CHECK_EQ(waitpid(pid, &status, 0), pid);
    int fd[2];
    open_nodes(bus, fd);
    CHECK_EQ(vt_write_all(fd[0], "ok", 2), 0);
    CHECK_EQ(vt_read_n(fd[1], dir, 2, WAIT_MS), 2);
    close_nodes(fd, 2);
    fap_vbus_close(bus);
}

UNIT_MAIN(
    UNIT(test_options_and_paths),
    UNIT(test_link_dir),
    UNIT(test_broadcast_not_to_sender),
    UNIT(test_echo),
    UNIT(test_child_program),
    UNIT(test_paced_frame_time),
    UNIT(test_collision),
    UNIT(test_drop_and_corrupt_next),
    UNIT(test_silence),
    UNIT(test_disconnect),
    UNIT(test_seeded_bit_errors_reproduce),
    UNIT(test_drop_rate),
    UNIT(test_capture),
    UNIT(test_overflow_does_not_block),
    UNIT(test_late_opener_starts_clean),
    UNIT(test_control_calls_from_many_threads),
    UNIT(test_sixty_four_ports),
    UNIT(test_exit_without_close_removes_links)
)
