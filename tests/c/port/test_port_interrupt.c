/* The port's own interrupt (port/port_cancel.h) and the listener's frame
 * read (lf_port_read_frame), on real ptys: an interrupt ends a read blocked
 * with no deadline, from another thread, and stays set; a partial frame
 * comes back after its wire time, not at the caller's deadline; a short
 * wait keeps its deadline to the nanosecond (lf_port_read_until). */
#include <pthread.h>

#include "fap_port.h"
#include "port/port_cancel.h"
#include "port/rx_pacing.h"
#include "unit.h"
#include "pty_util.h"

static fap_port_options opts(void)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = FAP_RS485_NONE;   /* 115200 baud */
    return o;
}

/* A pty and an interruptible port on it: 0, or -1 with nothing open. */
static int setup(test_pty *t, fap_port **p)
{
    fap_port_options o = opts();
    if (tp_open(t) != 0)
        return -1;
    if (lf_port_open_interruptible(p, t->name, &o) == 0)
        return 0;
    tp_close(t);
    return -1;
}

static void teardown(test_pty *t, fap_port *p)
{
    fap_port_close(p);   /* closes the interrupt's eventfd too */
    tp_close(t);
}

typedef struct reader {
    fap_port *p;
    ssize_t r;
} reader;

static void *read_forever(void *arg)
{
    reader *rd = arg;
    char b[16];
    rd->r = fap_port_read(rd->p, b, sizeof b, INT64_MAX);
    return NULL;
}

static void test_interrupt_ends_a_blocked_read(void)
{
    test_pty t;
    fap_port *p = NULL;
    MUST(setup(&t, &p) == 0);
    CHECK_EQ(lf_port_interrupted(p), 0);
    reader rd = {.p = p, .r = 1};
    pthread_t th;
    MUST(pthread_create(&th, NULL, read_forever, &rd) == 0);
    lf_port_interrupt(p);   /* before or during the wait: either way it ends */
    pthread_join(th, NULL);
    CHECK_EQ(rd.r, -ECANCELED);
    CHECK_EQ(lf_port_interrupted(p), 1);
    char b[4];
    CHECK_EQ(fap_port_read(p, b, sizeof b, INT64_MAX), -ECANCELED);   /* sticky */
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.read_errors, 0);   /* a stop is not a read error */
    teardown(&t, p);
}

static void test_interrupt_on_a_plain_port_is_a_flag(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = opts();
    fap_port *p = NULL;
    int fds = tp_count_fds();
    MUST(lf_port_open_interruptible(&p, t.name, &o) == 0);
    fap_port_close(p);
    CHECK_EQ(tp_count_fds(), fds);   /* nothing leaks */
    MUST(fap_port_open(&p, t.name, &o) == 0);
    lf_port_interrupt(p);
    CHECK_EQ(lf_port_interrupted(p), 1);
    char b[4];
    CHECK_EQ(fap_port_read(p, b, sizeof b, 0), 0);   /* no interrupt fd: waits as usual */
    fap_port_close(p);
    lf_port_interrupt(NULL);
    CHECK_EQ(lf_port_interrupted(NULL), 0);
    CHECK_EQ(lf_port_open_interruptible(NULL, t.name, &o), -EINVAL);
    tp_close(&t);
}

/* 3 bytes of a frame that needs 20: read_frame hands them over once their
 * wire time has passed; the caller's deadline (a minute) is not waited out. */
static void test_read_frame_returns_a_partial_frame(void)
{
    test_pty t;
    fap_port *p = NULL;
    MUST(setup(&t, &p) == 0);
    MUST(write(t.master, "abc", 3) == 3);
    char b[32];
    int64_t t0 = tp_now_ns();
    ssize_t r = lf_port_read_frame(p, b, sizeof b, 20, t0 + 60 * 1000000000LL);
    CHECK_EQ(r, 3);
    CHECK(tp_now_ns() - t0 < 30 * 1000000000LL);
    CHECK_MEM(b, "abc", 3);
    MUST(write(t.master, "de", 2) == 2);   /* the first bytes are waited for */
    CHECK_EQ(lf_port_read_frame(p, b, sizeof b, 2, INT64_MAX), 2);
    CHECK_EQ(lf_port_read_frame(NULL, b, sizeof b, 2, 0), -EINVAL);
    teardown(&t, p);
}

/* lf_port_read_until: bytes already there come at once; with none, it
 * returns 0 not before its deadline (a lower bound, never a speed claim),
 * for a deadline under a millisecond too. */
static void test_read_until(void)
{
    test_pty t;
    fap_port *p = NULL;
    MUST(setup(&t, &p) == 0);
    char b[8];
    int64_t dl = tp_now_ns() + 2500000;   /* 2.5 ms: poll part, then sleep */
    CHECK_EQ(lf_port_read_until(p, b, sizeof b, dl), 0);
    CHECK(tp_now_ns() >= dl);
    dl = tp_now_ns() + 300000;            /* 0.3 ms: sleep only */
    CHECK_EQ(lf_port_read_until(p, b, sizeof b, dl), 0);
    CHECK(tp_now_ns() >= dl);
    MUST(write(t.master, "xyz", 3) == 3);
    CHECK_EQ(lf_port_read_until(p, b, sizeof b, tp_now_ns() + 60 * 1000000000LL), 3);
    CHECK_MEM(b, "xyz", 3);
    CHECK_EQ(lf_port_read_until(p, b, sizeof b, 0), 0);   /* 0: no wait */
    lf_port_interrupt(p);
    CHECK_EQ(lf_port_read_until(p, b, sizeof b, INT64_MAX), -ECANCELED);
    CHECK_EQ(lf_port_read_until(NULL, b, sizeof b, 0), -EINVAL);
    teardown(&t, p);
}

UNIT_MAIN(UNIT(test_interrupt_ends_a_blocked_read), UNIT(test_interrupt_on_a_plain_port_is_a_flag),
          UNIT(test_read_frame_returns_a_partial_frame), UNIT(test_read_until))
