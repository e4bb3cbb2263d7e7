/* rx pacing (port/rx_pacing.h) through a fake backend with its own wire:
 * byte k of the script arrives at k character times (mid-character, so
 * microseconds of real scheduling never move a byte across a boundary),
 * on a clock that only the fake's poll and sleep_until advance. So every
 * test is deterministic: how many reads (wake-ups) and sleeps a read of a
 * frame costs, how long it sleeps, and that it never sleeps past the
 * deadline or when the bytes are already there. Also the decoders' "bytes
 * still missing" answers the engines feed it (FAP, exec async, mikroC). */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include "common/mono_clock.h"
#include "execasync/codec_internal.h"
#include "fap/codec.h"
#include "fap_port.h"
#include "mikroc/mikroc_internal.h"
#include "port/port_device.h"
#include "port/rx_pacing.h"
#include "unit.h"

#define BAUD 300                      /* 33.3 ms per character: wide margins */
#define CT ((int64_t)10 * 1000000000 / BAUD)

typedef struct wire {
    int pipefd[2];                    /* a real fd for the port's epoll set */
    int64_t skipped;                  /* virtual time added by poll/sleep */
    int64_t t0;                       /* virtual time of the script's start */
    size_t n;                         /* script length */
    int64_t at[64];                   /* virtual arrival time of each byte */
    size_t consumed;
    int reads, polls, sleeps;
    int64_t slept[8];                 /* durations asked of sleep_until */
} wire;

static int64_t vnow(wire *w) { return lf_now_ns() + w->skipped; }

static size_t arrived(wire *w)
{
    size_t k = 0;
    while (k < w->n && w->at[k] <= vnow(w))
        k++;
    return k;
}

/* n bytes, one per ct ns from now (mid-character); ct 0: all there at
 * once (an unpaced pty). */
static void script_at(wire *w, size_t n, int64_t ct)
{
    w->n = n;
    w->consumed = 0;
    w->t0 = vnow(w);
    for (size_t k = 0; k < n; k++)
        w->at[k] = w->t0 + (int64_t)k * ct + ct / 2;
    w->reads = w->polls = w->sleeps = 0;
}

/* all == 1: all there at once, else one per character time of BAUD. */
static void script(wire *w, size_t n, int all)
{
    script_at(w, n, all ? 0 : CT);
}

static int f_open(void *c, const char *p, int fl) { (void)p; (void)fl; return ((wire *)c)->pipefd[0]; }
static int f_close(void *c, int fd) { (void)c; (void)fd; return 0; }
static int f_ioctl(void *c, int fd, unsigned long r, void *a) { (void)c; (void)fd; (void)a; if (r == TIOCEXCL || r == TIOCNXCL) return 0; errno = ENOTTY; return -1; }
static int f_tcget(void *c, int fd, struct termios *t) { (void)c; (void)fd; memset(t, 0, sizeof *t); return 0; }
static int f_tcset(void *c, int fd, int a, const struct termios *t) { (void)c; (void)fd; (void)a; (void)t; return 0; }
static int f_tcflush(void *c, int fd, int q) { (void)c; (void)fd; (void)q; return 0; }
static int f_tcdrain(void *c, int fd) { (void)c; (void)fd; return 0; }
static int f_flock(void *c, int fd, int op) { (void)c; (void)fd; (void)op; return 0; }
static ssize_t f_write(void *c, int fd, const void *b, size_t n) { (void)c; (void)fd; (void)b; return (ssize_t)n; }

static ssize_t f_read(void *c, int fd, void *buf, size_t n)
{
    (void)fd;
    wire *w = c;
    w->reads++;
    size_t k = arrived(w) - w->consumed;
    if (k == 0) {
        errno = EAGAIN;
        return -1;
    }
    if (k > n)
        k = n;
    memset(buf, 0xA5, k);
    w->consumed += k;
    return (ssize_t)k;
}

/* Readable now, or jump the virtual clock to the next arrival if it comes
 * within the timeout (or to the timeout). */
static int f_poll(void *c, struct pollfd *p, nfds_t n, int ms)
{
    (void)n;
    wire *w = c;
    w->polls++;
    p->revents = 0;
    if (arrived(w) > w->consumed) {
        p->revents = POLLIN;
        return 1;
    }
    int64_t wait = ms < 0 ? INT64_MAX : (int64_t)ms * 1000000;
    if (w->consumed < w->n && w->at[w->consumed] - vnow(w) <= wait) {
        w->skipped += w->at[w->consumed] - vnow(w);
        p->revents = POLLIN;
        return 1;
    }
    if (ms > 0)
        w->skipped += wait;
    return 0;
}

/* The port computes deadlines on the real clock: the gap to it is what
 * the engine would have slept. */
static void f_sleep(void *c, int64_t deadline)
{
    wire *w = c;
    int64_t d = deadline - lf_now_ns();
    if (w->sleeps < 8)
        w->slept[w->sleeps] = d;
    w->sleeps++;
    if (d > 0)
        w->skipped += d;
}

/* The pace is measured on the wire's own clock. */
static int64_t f_now(void *c) { return vnow(c); }

static const lf_port_os fake_be = {
    .open = f_open, .close = f_close, .ioctl = f_ioctl, .tcgetattr = f_tcget,
    .tcsetattr = f_tcset, .tcflush = f_tcflush, .tcdrain = f_tcdrain, .flock = f_flock,
    .read = f_read, .write = f_write, .poll = f_poll, .sleep_until = f_sleep,
    .now = f_now,
};

static fap_port *open_fake(wire *w, unsigned baud)
{
    memset(w, 0, sizeof *w);
    if (pipe(w->pipefd) < 0)
        return NULL;
    fap_port_options o;
    fap_port_options_init(&o);
    o.baud = baud;
    o.rs485_mode = FAP_RS485_NONE;
    fap_port *p = NULL;
    if (lf_port_open_with_backend(&p, "/fake/tty", &o, &fake_be, w) < 0)
        return NULL;
    return p;
}

static void close_fake(wire *w, fap_port *p)
{
    fap_port_close(p);
    close(w->pipefd[0]);
    close(w->pipefd[1]);
}

static void test_hold_ns(void)
{
    lf_ns ct = lf_char_time_ns(115200);             /* 86.8 us: margin 150 us */
    CHECK_EQ(lf_rx_hold_ns(115200, 0), 0);
    CHECK_EQ(lf_rx_hold_ns(115200, 1), 0);          /* the last byte: wait on the fd */
    CHECK_EQ(lf_rx_hold_ns(115200, 3), 0);          /* 174 - 150 us: not worth a timer */
    CHECK_EQ(lf_rx_hold_ns(115200, 15), 14 * ct - 150000);
    CHECK_EQ(lf_rx_hold_ns(9600, 15), 13 * lf_char_time_ns(9600));  /* margin: 1 char */
    CHECK_EQ(lf_rx_hold_ns(1000000, 15), 0);        /* a short frame at 1 Mbaud */
    CHECK_EQ(lf_rx_hold_ns(1000000, 1039), 1038 * lf_char_time_ns(1000000) - 150000);
    CHECK_EQ(lf_rx_hold_ns(0, 15), 0);              /* baud unknown: never sleep */
}

/* An unpaced pty: the whole frame is queued: one read, no sleep. */
static void test_all_there_read_at_once(void)
{
    wire w;
    fap_port *p = open_fake(&w, BAUD);
    REQUIRE(p);
    script(&w, 15, 1);
    uint8_t buf[64];
    CHECK_EQ(lf_port_read_paced(p, buf, sizeof buf, 15, lf_now_ns() + 10 * CT), 15);
    CHECK_EQ(w.sleeps, 0);
    CHECK_EQ(w.reads, 1);
    CHECK_EQ(w.polls, 0);
    close_fake(&w, p);
}

/* A paced wire: wait for the first byte, then for the second (which shows
 * the link's pace: one character time), sleep 11 character times (all but
 * the last missing byte, less one character of margin), read the 11 that
 * came meanwhile at once, leave the last bytes to the caller's wait: a few
 * reads instead of 13 wake-ups. The sleep ends right where byte 12 lands
 * (the margin is one character here), so microseconds of real time decide
 * whether it is in: 12 or 13 bytes (a loaded machine: one more or
 * less), and a short extra sleep when one was missing. */
static void test_paced_frame_one_sleep(void)
{
    wire w;
    fap_port *p = open_fake(&w, BAUD);
    REQUIRE(p);
    script(&w, 15, 0);
    uint8_t buf[64];
    int64_t far = lf_now_ns() + 100 * CT;
    ssize_t r = lf_port_read_paced(p, buf, sizeof buf, 15, far);
    if (r < 11 || r > 14 || w.sleeps > 3)
        fprintf(stderr, "r %zd sleeps %d\n", r, w.sleeps);
    CHECK(r >= 11 && r <= 14);
    CHECK(w.sleeps >= 1 && w.sleeps <= 3);
    CHECK(w.slept[0] > 11 * CT - CT / 4 && w.slept[0] <= 11 * CT + CT / 4);
    CHECK_EQ(w.polls, 2);                            /* the first byte, the second */
    CHECK(w.reads <= 6);
    /* the last ones: too short a hold, a plain wait per byte */
    int sleeps = w.sleeps;
    size_t rest = (size_t)(15 - r);
    for (int i = 0; rest > 0 && i < 4; i++) {
        ssize_t k = lf_port_read_paced(p, buf, sizeof buf, rest, far);
        if (k <= 0)
            break;
        rest -= (size_t)k;
    }
    CHECK_EQ(rest, 0);
    CHECK_EQ(w.sleeps, sleeps);
    close_fake(&w, p);
}

/* The link is 10x faster than the port's baud (a 1 Mbaud bus read at
 * 115200, a network transport): the hold follows the observed pace, so it
 * never exceeds the frame's time on that link (before: 11 character times
 * of the baud, 10x too long). */
static void test_fast_link_short_hold(void)
{
    wire w;
    fap_port *p = open_fake(&w, BAUD);
    REQUIRE(p);
    script_at(&w, 15, CT / 10);
    uint8_t buf[64];
    ssize_t r = lf_port_read_paced(p, buf, sizeof buf, 15, lf_now_ns() + 100 * CT);
    CHECK(r >= 13 && r <= 15);
    CHECK(w.sleeps >= 1 && w.sleeps <= 2);
    int64_t slept = 0;
    for (int i = 0; i < w.sleeps; i++)
        slept += w.slept[i];
    CHECK(slept > 0 && slept <= 13 * CT / 10);       /* the frame's time on this link */
    close_fake(&w, p);
}

/* A link slower than the baud says: the hold keeps to the baud (the
 * smaller), so a byte is never read later than it can arrive. */
static void test_slow_link_baud_bounds_hold(void)
{
    wire w;
    fap_port *p = open_fake(&w, BAUD);
    REQUIRE(p);
    script_at(&w, 15, 3 * CT);
    uint8_t buf[64];
    ssize_t r = lf_port_read_paced(p, buf, sizeof buf, 15, lf_now_ns() + 100 * CT);
    CHECK(r >= 3 && r < 15);
    CHECK(w.sleeps >= 1);
    CHECK(w.slept[0] <= 11 * CT);
    close_fake(&w, p);
}

/* Never sleeps past the deadline, and returns what came by then. */
static void test_deadline_caps_sleep(void)
{
    wire w;
    fap_port *p = open_fake(&w, BAUD);
    REQUIRE(p);
    script(&w, 15, 0);
    uint8_t buf[64];
    int64_t start = lf_now_ns();
    int64_t deadline = start + 5 * CT;               /* real clock: the port's */
    ssize_t r = lf_port_read_paced(p, buf, sizeof buf, 15, deadline);
    CHECK(r >= 2 && r <= 7);
    CHECK_EQ(w.sleeps, 1);
    CHECK(w.slept[0] <= 5 * CT);
    close_fake(&w, p);
}

/* The sender stopped after 3 bytes: the wait for the next piece ends at
 * the deadline with the 3 bytes; no sleep. */
static void test_stalled_wire_returns(void)
{
    wire w;
    fap_port *p = open_fake(&w, BAUD);
    REQUIRE(p);
    script(&w, 3, 1);
    uint8_t buf[64];
    CHECK_EQ(lf_port_read_paced(p, buf, sizeof buf, 15, lf_now_ns() + 2 * CT), 3);
    CHECK_EQ(w.sleeps, 0);
    close_fake(&w, p);
}

/* A full buffer, or a deadline of 0: no sleep at all. */
static void test_no_sleep_cases(void)
{
    wire w;
    uint8_t buf[64];
    fap_port *p = open_fake(&w, BAUD);
    REQUIRE(p);
    script(&w, 15, 1);
    CHECK_EQ(lf_port_read_paced(p, buf, 4, 15, lf_now_ns() + 100 * CT), 4);  /* buffer full */
    CHECK_EQ(w.sleeps, 0);
    CHECK_EQ(lf_port_read_paced(p, buf, sizeof buf, 15, 0), 11);            /* no waiting */
    CHECK_EQ(lf_port_read_paced(p, buf, sizeof buf, 15, 0), 0);             /* nothing left */
    CHECK_EQ(lf_port_read_paced(NULL, buf, sizeof buf, 1, 0), -EINVAL);
    close_fake(&w, p);
}

static void test_fap_missing(void)
{
    lf_fap_decoder d;
    lf_fap_decoder_init(&d, 0);
    CHECK_EQ(lf_fap_decoder_missing(&d), 0);
    uint8_t f[64];
    size_t n = lf_fap_encode(f, sizeof f, LF_FAP_DATA, 1, 0, (const uint8_t *)"pingpong", 8);
    REQUIRE(n == 23);
    lf_fap_decoder_feed(&d, f, 5, 0, NULL, NULL);
    CHECK_EQ(lf_fap_decoder_missing(&d), 10);        /* size not in: a data-less frame */
    lf_fap_decoder_feed(&d, f + 5, 6, 0, NULL, NULL);
    CHECK_EQ(lf_fap_decoder_missing(&d), 12);        /* 23 - 11 */
    lf_fap_decoder_feed(&d, f + 11, 12, 0, NULL, NULL);
    CHECK_EQ(lf_fap_decoder_missing(&d), 0);         /* complete: reported, dropped */
    lf_fap_decoder_feed(&d, (const uint8_t *)"xyz", 3, 0, NULL, NULL);
    CHECK_EQ(lf_fap_decoder_missing(&d), 0);         /* garbage is not a frame */
}

static void test_exec_missing(void)
{
    struct execAsyncStateDef s;
    byte buf[EXEC_ASYNC_MAX_DATA];
    memset(&s, 0, sizeof s);
    CHECK_EQ(lf_exec_rx_missing(&s), 8);             /* DLE STX node seq DLE ETX crc crc */
    byte fr[64], data[2] = {1, 2};
    word n = execAsyncBufferOut(3, data, fr, 2, 0);
    REQUIRE(n == 10);
    size_t expect[] = {7, 6, 5, 4, 4, 4, 3, 2, 1};   /* after each byte but the last */
    for (word i = 0; i + 1 < n; i++) {
        CHECK(!execAsyncByteIn(fr[i], &s, buf));
        CHECK_EQ(lf_exec_rx_missing(&s), expect[i]);
    }
    CHECK(execAsyncByteIn(fr[n - 1], &s, buf));
}

static void test_mikroc_missing(void)
{
    mikrocRS485_decoder d;
    mikrocRS485_DecoderInit(&d);
    mikrocRS485_frame f;
    CHECK_EQ(lf_mikroc_missing(&d), 5);              /* START addr DL CRC STOP */
    uint8_t fr[16];
    int n = mikrocRS485_Encode(fr, (const uint8_t *)"abc", 3, 7, 1);
    REQUIRE(n == 8);
    size_t expect[] = {4, 3, 5, 4, 3, 2, 1};         /* DL says 3 data bytes */
    for (int i = 0; i + 1 < n; i++) {
        CHECK_EQ(mikrocRS485_DecoderFeed(&d, fr[i], &f), MIKROC_RS485_MORE);
        CHECK_EQ(lf_mikroc_missing(&d), expect[i]);
    }
    CHECK_EQ(mikrocRS485_DecoderFeed(&d, fr[n - 1], &f), MIKROC_RS485_FRAME);
}

/* What mikroC asks the port for: a full frame (8 bytes) until DATALEN
 * says the count, then exactly what is missing; a 1-byte frame's count. */
static void test_mikroc_expect(void)
{
    mikrocRS485_decoder d;
    mikrocRS485_DecoderInit(&d);
    mikrocRS485_frame f;
    CHECK_EQ(lf_mikroc_expect(&d), MIKROC_RS485_FRAME_MAX);
    uint8_t fr[16];
    int n = mikrocRS485_Encode(fr, (const uint8_t *)"a", 1, 7, 1);
    REQUIRE(n == 6);
    size_t expect[] = {7, 6, 3, 2, 1};                /* START, addr: guess; DL: exact */
    for (int i = 0; i + 1 < n; i++) {
        CHECK_EQ(mikrocRS485_DecoderFeed(&d, fr[i], &f), MIKROC_RS485_MORE);
        CHECK_EQ(lf_mikroc_expect(&d), expect[i]);
    }
    CHECK_EQ(mikrocRS485_DecoderFeed(&d, fr[n - 1], &f), MIKROC_RS485_FRAME);
    CHECK_EQ(lf_mikroc_expect(&d), MIKROC_RS485_FRAME_MAX);
}

/* lf_port_read_frame_kept: a frame at the baud's pace sets at_baud; the
 * next frame then holds from its first piece (one poll, no wait for a
 * second piece); a link 10x faster makes the trusted hold find its frame
 * complete on time, which clears at_baud (the next frame observes). */
static void test_frame_kept_pace(void)
{
    wire w;
    fap_port *p = open_fake(&w, BAUD);
    REQUIRE(p);
    uint8_t buf[64];
    lf_rx_link link = {0};
    script(&w, 15, 0);
    ssize_t r = lf_port_read_frame_kept(p, buf, sizeof buf, 15, lf_now_ns() + 100 * CT, &link);
    CHECK(r >= 11 && r <= 15);
    CHECK_EQ(w.polls, 2);                            /* the first piece, the second */
    CHECK_EQ(link.at_baud, 1);
    script(&w, 15, 0);
    r = lf_port_read_frame_kept(p, buf, sizeof buf, 15, lf_now_ns() + 100 * CT, &link);
    CHECK(r >= 11 && r <= 15);
    CHECK_EQ(w.polls, 1);                            /* the first piece only */
    CHECK(w.sleeps >= 1);
    CHECK_EQ(link.at_baud, 1);
    script_at(&w, 15, CT / 10);
    r = lf_port_read_frame_kept(p, buf, sizeof buf, 15, lf_now_ns() + 100 * CT, &link);
    CHECK_EQ(r, 15);
    CHECK_EQ(link.at_baud, 0);
    close_fake(&w, p);
}

/* lf_port_read_reply: 16 bytes at the baud's pace starting 1 character
 * after the request's end (the responder's latency); not_before = the
 * end + 16 characters. With at_baud: one sleep, one read, no poll; the
 * last byte is left for the caller's wait on the fd (the hold's rule).
 * Without at_baud, or nothing there at the wake: the fd as before. A
 * reply complete at an on-time wake (a link 10x faster) clears at_baud. */
static void shift(wire *w, int64_t by)
{
    for (size_t k = 0; k < w->n; k++)
        w->at[k] += by;
}

static void test_reply_one_sleep(void)
{
    wire w;
    fap_port *p = open_fake(&w, BAUD);
    REQUIRE(p);
    uint8_t buf[64];
    lf_rx_link link = {1};
    script(&w, 16, 0);
    shift(&w, CT);
    int64_t not_before = lf_now_ns() + 16 * CT;
    ssize_t r = lf_port_read_reply(p, buf, sizeof buf, 16, not_before, lf_now_ns() + 100 * CT,
                                   &link);
    CHECK_EQ(r, 15);
    CHECK_EQ(w.sleeps, 1);
    CHECK_EQ(w.polls, 0);
    CHECK_EQ(w.reads, 1);
    CHECK_EQ(link.at_baud, 1);

    /* the deadline comes first: the sleep ends there, what is in is returned */
    script(&w, 16, 0);
    shift(&w, CT);
    r = lf_port_read_reply(p, buf, sizeof buf, 16, lf_now_ns() + 16 * CT, lf_now_ns() + 8 * CT,
                           &link);
    CHECK(r >= 6 && r <= 8);
    CHECK_EQ(w.sleeps, 1);
    CHECK(w.slept[0] <= 8 * CT);

    /* a slow responder: nothing at the wake, then the first piece on the fd */
    script(&w, 16, 0);
    shift(&w, 30 * CT);
    r = lf_port_read_reply(p, buf, sizeof buf, 16, lf_now_ns() + 16 * CT, lf_now_ns() + 100 * CT,
                           &link);
    CHECK(r >= 1);
    CHECK(w.polls >= 1);
    CHECK_EQ(link.at_baud, 1);

    /* a faster link: complete at the wake, which clears at_baud */
    script_at(&w, 16, CT / 10);
    r = lf_port_read_reply(p, buf, sizeof buf, 16, lf_now_ns() + 16 * CT, lf_now_ns() + 100 * CT,
                           &link);
    CHECK_EQ(r, 16);
    CHECK_EQ(link.at_baud, 0);

    /* at_baud clear: no sleep before the first piece */
    script(&w, 16, 0);
    r = lf_port_read_reply(p, buf, sizeof buf, 16, lf_now_ns() + 16 * CT, lf_now_ns() + 100 * CT,
                           &link);
    CHECK(r >= 1);
    CHECK(w.polls >= 1);
    CHECK(w.sleeps == 0 || w.slept[0] < 16 * CT);
    CHECK_EQ(lf_port_read_reply(p, buf, sizeof buf, 16, 0, 0, NULL), -EINVAL);
    close_fake(&w, p);

    /* 16 bytes at 1 Mbaud (160 us): too short for a hold, so no sleep */
    p = open_fake(&w, 1000000);
    REQUIRE(p);
    link.at_baud = 1;
    script_at(&w, 16, 10000);
    shift(&w, 10000);
    r = lf_port_read_reply(p, buf, sizeof buf, 16, lf_now_ns() + 160000, lf_now_ns() + 100 * CT,
                           &link);
    CHECK(r >= 1);
    CHECK_EQ(w.sleeps, 0);
    /* at most one poll: a slow build (TSan) may find the first byte already in */
    CHECK(w.polls <= 1);
    close_fake(&w, p);
}

UNIT_MAIN(UNIT(test_hold_ns), UNIT(test_reply_one_sleep), UNIT(test_all_there_read_at_once),
          UNIT(test_paced_frame_one_sleep), UNIT(test_fast_link_short_hold),
          UNIT(test_slow_link_baud_bounds_hold), UNIT(test_frame_kept_pace),
          UNIT(test_deadline_caps_sleep),
          UNIT(test_stalled_wire_returns), UNIT(test_no_sleep_cases),
          UNIT(test_fap_missing), UNIT(test_exec_missing), UNIT(test_mikroc_missing),
          UNIT(test_mikroc_expect))
