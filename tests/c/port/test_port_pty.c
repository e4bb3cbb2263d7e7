/* Port layer on real ptys: open/close per mode, errors, exclusivity, round
 * trips, deadline reads, partial writes, echo suppression, turnaround,
 * vanished device and reopen. The test plays the far end on the master. */
#include <pthread.h>
#include <stdlib.h>
#include <sys/stat.h>

#include "fap_port.h"
#include "pty_util.h"
#include "unit.h"

static fap_port_options opts_mode(fap_rs485_mode m)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = m;
    return o;
}

static void test_options_defaults(void)
{
    fap_port_options o;
    memset(&o, 0xAB, sizeof o);
    fap_port_options_init(&o);
    CHECK_EQ(o.baud, 115200);
    CHECK_EQ(o.rs485_mode, FAP_RS485_AUTO);
    CHECK_EQ(o.rts_active_high, FAP_PORT_KEEP);   /* not given: the device's */
    CHECK_EQ(o.exclusive, 1);
    CHECK_EQ(o.echo_suppression, 0);
    CHECK_EQ(o.echo_timeout_us, 0);
    CHECK_EQ(o.turnaround_us, 0);
    CHECK_EQ(o.delay_before_send_us, FAP_PORT_KEEP_DELAY);
    CHECK_EQ(o.delay_after_send_us, FAP_PORT_KEEP_DELAY);
    CHECK_EQ(o.rx_during_tx, FAP_PORT_KEEP);
    CHECK_EQ(o.write_timeout_us, 0);
}

static void test_open_close_none(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.baud = 9600;
    fap_port *p = NULL;
    CHECK_EQ(fap_port_open(&p, t.name, &o), 0);
    MUST(p != NULL);
    CHECK_EQ(fap_port_mode(p), FAP_RS485_NONE);
    CHECK(fap_port_fd(p) >= 0);
    CHECK(strcmp(fap_port_path(p), t.name) == 0);
    CHECK_EQ(fap_port_baud(p), 9600);
    CHECK_EQ(fap_port_auto_errno(p), 0);
    fap_port_close(p);
    fap_port_close(NULL);
    tp_close(&t);
}

static void test_auto_on_pty_is_none(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port *p = NULL;
    CHECK_EQ(fap_port_open(&p, t.name, NULL), 0);   /* NULL = defaults = AUTO */
    MUST(p != NULL);
    CHECK_EQ(fap_port_mode(p), FAP_RS485_NONE);
    CHECK_EQ(fap_port_auto_errno(p), ENOTTY);
    CHECK(strcmp(fap_rs485_mode_name(fap_port_mode(p)), "none") == 0);
    fap_port_close(p);
    tp_close(&t);
}

/* An explicit mode the pty refuses: -ENOTTY, *out untouched, no fd leaked,
 * and the path is free again right after. */
static void check_explicit_refused(fap_rs485_mode m)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    int fds_before = tp_count_fds();
    fap_port_options o = opts_mode(m);
    fap_port *p = (fap_port *)&t;   /* sentinel: must stay as is */
    CHECK_EQ(fap_port_open(&p, t.name, &o), -ENOTTY);
    CHECK(p == (fap_port *)&t);
    CHECK_EQ(tp_count_fds(), fds_before);
    fap_port *q = NULL;
    o = opts_mode(FAP_RS485_NONE);
    CHECK_EQ(fap_port_open(&q, t.name, &o), 0);
    fap_port_close(q);
    tp_close(&t);
}

static void test_explicit_kernel_on_pty(void) { check_explicit_refused(FAP_RS485_KERNEL); }
static void test_explicit_soft_rts_on_pty(void) { check_explicit_refused(FAP_RS485_SOFT_RTS); }

static void test_open_errors(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    int fds_before = tp_count_fds();
    fap_port *p = NULL;
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.baud = 12345;
    CHECK_EQ(fap_port_open(&p, t.name, &o), -EINVAL);
    o.baud = 0;
    CHECK_EQ(fap_port_open(&p, t.name, &o), -EINVAL);
    o = opts_mode((fap_rs485_mode)42);
    CHECK_EQ(fap_port_open(&p, t.name, &o), -EINVAL);
    o = opts_mode(FAP_RS485_NONE);
    CHECK_EQ(fap_port_open(&p, "/nonexistent/ttyFAP0", &o), -ENOENT);
    CHECK_EQ(fap_port_open(&p, "/dev/null", &o), -ENOTTY);   /* not a tty */
    o.exclusive = 0;
    CHECK_EQ(fap_port_open(&p, "/dev/null", &o), -ENOTTY);
    CHECK_EQ(fap_port_open(NULL, t.name, &o), -EINVAL);
    CHECK_EQ(fap_port_open(&p, NULL, &o), -EINVAL);
    CHECK(p == NULL);
    CHECK_EQ(tp_count_fds(), fds_before);
    /* Standard rates up to 4 Mbaud are accepted (a pty ignores them). */
    static const unsigned rates[] = {300, 9600, 19200, 57600, 230400, 921600, 4000000};
    for (size_t i = 0; i < sizeof rates / sizeof rates[0]; i++) {
        o = opts_mode(FAP_RS485_NONE);
        o.baud = rates[i];
        CHECK_EQ(fap_port_open(&p, t.name, &o), 0);
        fap_port_close(p);
        p = NULL;
    }
    tp_close(&t);
}

static void test_exclusive(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    fap_port *a = NULL, *b = NULL;
    CHECK_EQ(fap_port_open(&a, t.name, &o), 0);
    CHECK_EQ(fap_port_open(&b, t.name, &o), -EBUSY);
    CHECK(b == NULL);
    o.exclusive = 0;   /* asking politely does not get around the owner */
    CHECK_EQ(fap_port_open(&b, t.name, &o), -EBUSY);
    fap_port_close(a);
    o.exclusive = 1;
    CHECK_EQ(fap_port_open(&b, t.name, &o), 0);   /* free again */
    fap_port_close(b);
    /* Two non-exclusive openers may share, knowingly. */
    o.exclusive = 0;
    a = b = NULL;
    CHECK_EQ(fap_port_open(&a, t.name, &o), 0);
    CHECK_EQ(fap_port_open(&b, t.name, &o), 0);
    fap_port_close(a);
    fap_port_close(b);
    tp_close(&t);
}

static void test_round_trip(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    CHECK_EQ(fap_port_write(p, "hello\n\r\x00\xff", 9), 9);
    char m[16];
    CHECK_EQ(tp_read_exact(t.master, m, 9, 2000), 9);
    CHECK_MEM(m, "hello\n\r\x00\xff", 9);   /* raw: no CR/NL mangling */
    CHECK_EQ(tp_write_all(t.master, "\x13\x11world", 7, 2000), 7);
    char in[16];
    size_t got = 0;
    int64_t deadline = fap_port_now_ns() + 2000000000LL;
    while (got < 7) {
        ssize_t r = fap_port_read(p, in + got, sizeof in - got, deadline);
        if (r <= 0)
            break;
        got += (size_t)r;
    }
    CHECK_EQ(got, 7);
    CHECK_MEM(in, "\x13\x11world", 7);   /* XON/XOFF are data */
    /* INT64_MAX: wait as long as it takes (the byte is already on its way). */
    CHECK_EQ(tp_write_all(t.master, "!", 1, 1000), 1);
    CHECK_EQ(fap_port_read(p, in, sizeof in, INT64_MAX), 1);
    CHECK_EQ(in[0], '!');
    CHECK_EQ(fap_port_write(p, "", 0), 0);
    CHECK_EQ(fap_port_write(p, NULL, 1), -EINVAL);
    CHECK_EQ(fap_port_read(p, NULL, 1, 0), -EINVAL);
    CHECK_EQ(fap_port_write(NULL, "x", 1), -EINVAL);
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.tx_bytes, 9);
    CHECK_EQ(st.rx_bytes, 8);
    CHECK_EQ(st.write_errors, 0);
    fap_port_close(p);
    tp_close(&t);
}

static void test_deadline_read(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    char b[8];
    int64_t t0 = fap_port_now_ns();
    CHECK_EQ(fap_port_read(p, b, sizeof b, 0), 0);   /* no wait */
    CHECK_EQ(fap_port_read(p, b, sizeof b, t0 - 1), 0);   /* past */
    t0 = fap_port_now_ns();
    CHECK_EQ(fap_port_read(p, b, sizeof b, t0 + 30 * 1000000LL), 0);
    int64_t el = fap_port_now_ns() - t0;
    CHECK(el >= 30 * 1000000LL);
    CHECK(el < 3000 * 1000000LL);
    fap_port_close(p);
    tp_close(&t);
}

static void test_flush(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    CHECK_EQ(tp_write_all(t.master, "stale", 5, 1000), 5);
    /* wait (with a deadline, not a sleep) until the bytes are readable */
    struct pollfd pf = {.fd = fap_port_fd(p), .events = POLLIN};
    CHECK_EQ(poll(&pf, 1, 2000), 1);
    CHECK_EQ(fap_port_flush(p), 0);
    char b[8];
    CHECK_EQ(fap_port_read(p, b, sizeof b, 0), 0);
    fap_port_close(p);
    tp_close(&t);
}

/* ---- partial writes ---------------------------------------------------- */

typedef struct drain_job {
    int fd;
    size_t want;
    uint8_t *buf;
    size_t got;
} drain_job;

static void *drain_thread(void *arg)
{
    drain_job *j = arg;
    j->got = tp_read_exact(j->fd, j->buf, j->want, 10000);
    return NULL;
}

static void test_partial_writes_64k(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.baud = 4000000;
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    enum { N = 65536 };
    uint8_t *out = malloc(N), *in = malloc(N);
    MUST(out && in);
    for (size_t i = 0; i < N; i++)
        out[i] = (uint8_t)(i * 7 + (i >> 8));
    drain_job j = {.fd = t.master, .want = N, .buf = in};
    pthread_t th;
    MUST(pthread_create(&th, NULL, drain_thread, &j) == 0);
    CHECK_EQ(fap_port_write(p, out, N), N);   /* far more than a pty buffers */
    pthread_join(th, NULL);
    CHECK_EQ(j.got, N);
    CHECK_MEM(in, out, N);
    free(out);
    free(in);
    fap_port_close(p);
    tp_close(&t);
}

static void test_write_timeout_when_nobody_drains(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.write_timeout_us = 50000;
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    enum { N = 1 << 20 };
    uint8_t *out = calloc(1, N);
    MUST(out);
    CHECK_EQ(fap_port_write(p, out, N), -ETIMEDOUT);   /* never blocks forever */
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.write_errors, 1);
    CHECK(st.tx_bytes > 0 && st.tx_bytes < N);
    free(out);
    fap_port_close(p);
    tp_close(&t);
}

/* ---- echo suppression ---------------------------------------------------- */

typedef struct echo_job {
    int fd;
    size_t n;              /* bytes to echo */
    size_t corrupt_at;     /* flip this byte (SIZE_MAX: none) */
    const char *after;     /* bytes the far end sends right behind the echo */
    size_t echoed;
} echo_job;

static void *echo_thread(void *arg)
{
    echo_job *j = arg;
    uint8_t buf[4096 + 64];
    while (j->echoed < j->n) {
        size_t want = j->n - j->echoed;
        if (want > 4096)
            want = 4096;
        size_t r = tp_read_exact(j->fd, buf, 1, 10000);
        if (r != 1)
            break;
        ssize_t more = read(j->fd, buf + 1, want - 1);
        size_t len = 1 + (more > 0 ? (size_t)more : 0);
        if (j->corrupt_at >= j->echoed && j->corrupt_at < j->echoed + len)
            buf[j->corrupt_at - j->echoed] ^= 0x5A;
        size_t tail = 0;
        if (j->echoed + len == j->n && j->after) {   /* same write as the echo */
            tail = strlen(j->after);
            memcpy(buf + len, j->after, tail);
        }
        if (tp_write_all(j->fd, buf, len + tail, 10000) != len + tail)
            break;
        j->echoed += len;
    }
    return NULL;
}

static void run_echo_case(size_t n, size_t corrupt_at, const char *after, ssize_t expect)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.echo_suppression = 1;
    o.echo_timeout_us = 2000000;   /* generous: sanitizers are slow */
    o.baud = 4000000;
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    uint8_t *out = malloc(n);
    MUST(out);
    for (size_t i = 0; i < n; i++)
        out[i] = (uint8_t)(i * 13 + 1);
    echo_job j = {.fd = t.master, .n = n, .corrupt_at = corrupt_at, .after = after};
    pthread_t th;
    MUST(pthread_create(&th, NULL, echo_thread, &j) == 0);
    CHECK_EQ(fap_port_write(p, out, n), expect);
    pthread_join(th, NULL);
    CHECK_EQ(j.echoed, n);
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.echo_bytes, n);
    CHECK_EQ(st.tx_bytes, n);
    CHECK_EQ(st.collisions, expect == FAP_PORT_ECOLLISION ? 1 : 0);
    if (after) {   /* the answer behind the echo is intact, echo is gone */
        size_t alen = strlen(after);
        char in[64] = {0};
        size_t got = 0;
        int64_t deadline = fap_port_now_ns() + 2000000000LL;
        while (got < alen) {
            ssize_t r = fap_port_read(p, in + got, sizeof in - got, deadline);
            if (r <= 0)
                break;
            got += (size_t)r;
        }
        CHECK_EQ(got, alen);
        CHECK_MEM(in, after, alen);
        CHECK_EQ(fap_port_read(p, in, sizeof in, 0), 0);
    }
    free(out);
    fap_port_close(p);
    tp_close(&t);
}

static void test_echo_dropped(void) { run_echo_case(10, SIZE_MAX, NULL, 10); }
static void test_echo_then_answer_kept(void) { run_echo_case(10, SIZE_MAX, "ANSWER", 10); }
static void test_echo_collision(void) { run_echo_case(10, 4, "ANSWER", FAP_PORT_ECOLLISION); }
static void test_echo_64k(void) { run_echo_case(65536, SIZE_MAX, "TAIL", 65536); }
static void test_echo_64k_collision(void) { run_echo_case(65536, 40000, NULL, FAP_PORT_ECOLLISION); }

/* A reader thread and a writer thread share a port with echo suppression:
 * the reader must see every answer byte and never a byte of our echo. */
enum { CONC_FRAMES = 200, CONC_LEN = 24 };

typedef struct conc_far_end {
    int fd;
    size_t echoed;
} conc_far_end;

static void *conc_far_end_thread(void *arg)
{
    conc_far_end *j = arg;
    uint8_t buf[CONC_LEN * 2 + 8];
    size_t total = (size_t)CONC_FRAMES * CONC_LEN;
    while (j->echoed < total) {
        size_t in_frame = j->echoed % CONC_LEN;
        size_t want = CONC_LEN - in_frame;   /* never past a frame end */
        if (tp_read_exact(j->fd, buf, 1, 10000) != 1)
            break;
        ssize_t more = read(j->fd, buf + 1, want - 1);
        size_t len = 1 + (more > 0 ? (size_t)more : 0);
        size_t out = len;
        if (in_frame + len == CONC_LEN)
            buf[out++] = 'Z';   /* the answer rides right behind the echo */
        if (tp_write_all(j->fd, buf, out, 10000) != out)
            break;
        j->echoed += len;
    }
    return NULL;
}

typedef struct conc_reader {
    fap_port *p;
    size_t got;
    size_t foreign;   /* bytes that were not answers: leaked echo */
    int err;
} conc_reader;

static void *conc_reader_thread(void *arg)
{
    conc_reader *r = arg;
    uint8_t b[64];
    while (r->got + r->foreign < CONC_FRAMES) {
        ssize_t n = fap_port_read(r->p, b, sizeof b, fap_port_now_ns() + 10000000000LL);
        if (n <= 0) {
            r->err = (int)n;
            break;
        }
        for (ssize_t i = 0; i < n; i++) {
            if (b[i] == 'Z')
                r->got++;
            else
                r->foreign++;
        }
    }
    return NULL;
}

static void test_echo_with_concurrent_reader(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.echo_suppression = 1;
    o.echo_timeout_us = 5000000;
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    conc_far_end fe = {.fd = t.master};
    conc_reader rd = {.p = p};
    pthread_t th_fe, th_rd;
    MUST(pthread_create(&th_fe, NULL, conc_far_end_thread, &fe) == 0);
    MUST(pthread_create(&th_rd, NULL, conc_reader_thread, &rd) == 0);
    uint8_t frame[CONC_LEN];
    int ok = 0;
    for (int i = 0; i < CONC_FRAMES; i++) {
        for (size_t k = 0; k < CONC_LEN; k++)
            frame[k] = (uint8_t)('a' + (i + k) % 26 - ((i + k) % 26 == 25));   /* never 'Z' */
        ok += fap_port_write(p, frame, CONC_LEN) == CONC_LEN;
    }
    pthread_join(th_fe, NULL);
    pthread_join(th_rd, NULL);
    CHECK_EQ(ok, CONC_FRAMES);
    CHECK_EQ(rd.err, 0);
    CHECK_EQ(rd.got, CONC_FRAMES);
    CHECK_EQ(rd.foreign, 0);
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.echo_bytes, CONC_FRAMES * CONC_LEN);
    CHECK_EQ(st.rx_bytes, CONC_FRAMES);
    CHECK_EQ(st.collisions, 0);
    fap_port_close(p);
    tp_close(&t);
}

/* Input that was already queued when an echo-suppressed write starts is
 * not echo: it is kept, returned first, and fap_port_fd() stays readable
 * for it even though the device queue is empty by then. */
static void test_echo_keeps_earlier_input(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.echo_suppression = 1;
    o.echo_timeout_us = 2000000;
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    CHECK_EQ(tp_write_all(t.master, "EARLY", 5, 1000), 5);
    struct pollfd pf = {.fd = fap_port_fd(p), .events = POLLIN};
    CHECK_EQ(poll(&pf, 1, 2000), 1);   /* queued on the device */

    echo_job j = {.fd = t.master, .n = 6, .corrupt_at = SIZE_MAX, .after = "LATE"};
    pthread_t th;
    MUST(pthread_create(&th, NULL, echo_thread, &j) == 0);
    CHECK_EQ(fap_port_write(p, "frame!", 6), 6);
    pthread_join(th, NULL);
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.collisions, 0);
    CHECK_EQ(st.echo_bytes, 6);

    pf.revents = 0;
    CHECK_EQ(poll(&pf, 1, 0), 1);   /* the parked bytes keep the fd readable */
    char in[16] = {0};
    size_t got = 0;
    int64_t deadline = fap_port_now_ns() + 2000000000LL;
    while (got < 9) {
        ssize_t r = fap_port_read(p, in + got, sizeof in - got, deadline);
        if (r <= 0)
            break;
        got += (size_t)r;
    }
    CHECK_EQ(got, 9);
    CHECK_MEM(in, "EARLYLATE", 9);
    pf.revents = 0;
    CHECK_EQ(poll(&pf, 1, 0), 0);   /* nothing left: not readable any more */
    CHECK_EQ(fap_port_read(p, in, sizeof in, 0), 0);
    fap_port_close(p);
    tp_close(&t);
}

static void test_echo_missing(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.echo_suppression = 1;
    o.echo_timeout_us = 20000;
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    CHECK_EQ(fap_port_write(p, "ping", 4), -ETIMEDOUT);
    char m[4];
    CHECK_EQ(tp_read_exact(t.master, m, 4, 1000), 4);   /* it was sent */
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.write_errors, 1);
    CHECK_EQ(st.echo_bytes, 0);
    CHECK(fap_port_fd(p) >= 0);   /* a missing echo is not a dead device */
    fap_port_close(p);
    tp_close(&t);
}

/* ---- turnaround ---------------------------------------------------------- */

static void test_turnaround(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts_mode(FAP_RS485_NONE);
    o.turnaround_us = 40000;
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    /* Nothing received yet: no wait. */
    CHECK_EQ(fap_port_write(p, "a", 1), 1);
    CHECK_EQ(tp_write_all(t.master, "q", 1, 1000), 1);
    char c;
    CHECK_EQ(fap_port_read(p, &c, 1, fap_port_now_ns() + 2000000000LL), 1);
    int64_t t_rx = fap_port_now_ns();
    CHECK_EQ(fap_port_write(p, "r", 1), 1);
    CHECK(fap_port_now_ns() - t_rx >= 40000000LL - 1000000LL);   /* loose lower bound */
    char m[2];
    CHECK_EQ(tp_read_exact(t.master, m, 2, 1000), 2);
    CHECK_MEM(m, "ar", 2);
    fap_port_close(p);
    tp_close(&t);
}

/* ---- vanished device and reopen ------------------------------------------ */

static void test_vanish_and_reopen(void)
{
    char dir[] = "/tmp/fap_port_testXXXXXX";
    MUST(mkdtemp(dir) != NULL);
    char link[sizeof dir + 16];
    snprintf(link, sizeof link, "%s/ttyFAP", dir);
    test_pty t1;
    MUST(tp_open(&t1) == 0);
    MUST(symlink(t1.name, link) == 0);
    fap_port_options o = opts_mode(FAP_RS485_AUTO);
    fap_port *p = NULL;
    int fds_closed = tp_count_fds();
    MUST(fap_port_open(&p, link, &o) == 0);
    CHECK_EQ(tp_count_fds(), fds_closed + 3);   /* device, epoll, eventfd */
    CHECK_EQ(fap_port_write(p, "x", 1), 1);

    int pfd = fap_port_fd(p);
    tp_close(&t1);   /* the USB plug is pulled */
    struct pollfd pf = {.fd = pfd, .events = POLLIN};
    CHECK_EQ(poll(&pf, 1, 5000), 1);   /* a poller wakes up for the hang-up */
    char b[8];
    CHECK_EQ(fap_port_read(p, b, sizeof b, fap_port_now_ns() + 5000000000LL), -EIO);
    CHECK_EQ(fap_port_fd(p), -1);
    CHECK_EQ(tp_count_fds(), fds_closed + 2 - 1);   /* device closed; t1 master too */
    CHECK_EQ(fap_port_write(p, "x", 1), -EIO);
    CHECK_EQ(fap_port_read(p, b, sizeof b, 0), -EIO);
    CHECK_EQ(fap_port_flush(p), -EIO);

    /* The device is not back yet: reopen fails, the port stays usable. */
    unlink(link);
    CHECK_EQ(fap_port_reopen(p), -ENOENT);
    CHECK_EQ(fap_port_fd(p), -1);
    CHECK_EQ(fap_port_write(p, "x", 1), -ENOENT);

    test_pty t2;
    MUST(tp_open(&t2) == 0);
    MUST(symlink(t2.name, link) == 0);
    CHECK_EQ(fap_port_reopen(p), 0);
    CHECK(fap_port_fd(p) >= 0);
    CHECK_EQ(fap_port_mode(p), FAP_RS485_NONE);
    CHECK_EQ(fap_port_write(p, "back", 4), 4);
    char m[4];
    CHECK_EQ(tp_read_exact(t2.master, m, 4, 2000), 4);
    CHECK_MEM(m, "back", 4);
    CHECK_EQ(tp_write_all(t2.master, "ok", 2, 1000), 2);
    CHECK_EQ(fap_port_read(p, b, 2, fap_port_now_ns() + 2000000000LL) > 0, 1);
    /* reopen of a healthy port works too (and keeps exclusivity sane) */
    CHECK_EQ(fap_port_reopen(p), 0);
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.reopens, 2);
    CHECK(st.read_errors >= 1);

    /* The write side notices too. */
    tp_close(&t2);
    ssize_t w = fap_port_write(p, "y", 1);
    CHECK(w == -EIO || w == 1);   /* a pty may accept one byte before it notices */
    if (w == 1)
        CHECK_EQ(fap_port_read(p, b, sizeof b, fap_port_now_ns() + 5000000000LL), -EIO);
    CHECK_EQ(fap_port_fd(p), -1);
    fap_port_close(p);
    unlink(link);
    rmdir(dir);
}

static void test_strerror(void)
{
    CHECK(strstr(fap_port_strerror(FAP_PORT_ECOLLISION), "collision") != NULL);
    CHECK(strstr(fap_port_strerror(FAP_PORT_ECLOSED), "closed") != NULL);
    CHECK(strcmp(fap_port_strerror(-ENOTTY), "Inappropriate ioctl for device") == 0);
    CHECK(strcmp(fap_port_strerror(EBUSY), fap_port_strerror(-EBUSY)) == 0);
    CHECK(strcmp(fap_port_strerror(0), "success") == 0);
    CHECK(strcmp(fap_port_strerror(-99999), "unknown error") == 0);
    CHECK(strcmp(fap_rs485_mode_name(FAP_RS485_KERNEL), "kernel") == 0);
    CHECK(strcmp(fap_rs485_mode_name(FAP_RS485_SOFT_RTS), "soft-rts") == 0);
    CHECK(strcmp(fap_rs485_mode_name(FAP_RS485_AUTO), "auto") == 0);
    CHECK(strcmp(fap_rs485_mode_name((fap_rs485_mode)9), "unknown") == 0);
}

UNIT_MAIN(UNIT(test_options_defaults), UNIT(test_open_close_none),
          UNIT(test_auto_on_pty_is_none), UNIT(test_explicit_kernel_on_pty),
          UNIT(test_explicit_soft_rts_on_pty), UNIT(test_open_errors),
          UNIT(test_exclusive), UNIT(test_round_trip), UNIT(test_deadline_read),
          UNIT(test_flush), UNIT(test_partial_writes_64k),
          UNIT(test_write_timeout_when_nobody_drains), UNIT(test_echo_dropped),
          UNIT(test_echo_then_answer_kept), UNIT(test_echo_collision),
          UNIT(test_echo_64k), UNIT(test_echo_64k_collision), UNIT(test_echo_missing), UNIT(test_echo_keeps_earlier_input),
          UNIT(test_echo_with_concurrent_reader),
          UNIT(test_turnaround), UNIT(test_vanish_and_reopen), UNIT(test_strerror))
