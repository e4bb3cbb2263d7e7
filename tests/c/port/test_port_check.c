/* fap_port_check_direction on a real pty whose far end plays a transceiver
 * with RX during TX: a thread echoes every byte back (or alters one, or
 * stays silent): rounds, echoed rounds, collisions, argument checks. */
#include <pthread.h>
#include <stdatomic.h>

#include "fap_port.h"
#include "pty_util.h"
#include "unit.h"

typedef struct echoer {
    int fd;
    int alter;            /* flip the 3rd byte of what comes back */
    atomic_int stop;
} echoer;

static void *echo_loop(void *arg)
{
    echoer *e = arg;
    uint8_t buf[256];
    size_t seen = 0;
    while (!atomic_load(&e->stop)) {
        struct pollfd pf = {.fd = e->fd, .events = POLLIN};
        if (poll(&pf, 1, 20) <= 0)
            continue;
        ssize_t r = read(e->fd, buf, sizeof buf);
        if (r <= 0)
            continue;
        for (ssize_t i = 0; i < r; i++, seen++)
            if (e->alter && seen % 32 == 2)
                buf[i] ^= 0xFF;
        tp_write_all(e->fd, buf, (size_t)r, 1000);
    }
    return NULL;
}

static fap_port *open_none(const char *path, int echo_suppression)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = FAP_RS485_NONE;
    o.echo_suppression = echo_suppression;
    fap_port *p = NULL;
    return fap_port_open(&p, path, &o) == 0 ? p : NULL;
}

static void run_check(int alter, int silent, fap_port_check *out, int *rc)
{
    test_pty t;
    *rc = -1;
    if (tp_open(&t) != 0)
        return;
    fap_port *p = open_none(t.name, 0);
    echoer e = {.fd = t.master, .alter = alter};
    pthread_t th;
    if (p && !silent)
        pthread_create(&th, NULL, echo_loop, &e);
    uint8_t pat[32];
    for (size_t i = 0; i < sizeof pat; i++)
        pat[i] = (uint8_t)(0x55 ^ i);
    if (p)
        *rc = fap_port_check_direction(p, pat, sizeof pat, 3, silent ? 50 : 2000, out);
    if (p && !silent) {
        atomic_store(&e.stop, 1);
        pthread_join(th, NULL);
    }
    fap_port_close(p);
    tp_close(&t);
}

static void test_check_echoing_pty(void)
{
    fap_port_check c;
    int rc;
    run_check(0, 0, &c, &rc);
    CHECK_EQ(rc, 0);
    CHECK_EQ(c.rounds, 3);
    CHECK_EQ(c.echoed, 3);
    CHECK_EQ(c.collisions, 0);
    /* the sign is the scheduler's here (both ends are this process's
     * threads); the paced virtual bus test checks a frame-long margin */
    for (unsigned i = 0; i < c.echoed; i++)
        CHECK(c.margin_ns[i] > -2000000000LL && c.margin_ns[i] < 2000000000LL);
}

static void test_check_counts_collisions(void)
{
    fap_port_check c;
    int rc;
    run_check(1, 0, &c, &rc);
    CHECK_EQ(rc, 0);
    CHECK_EQ(c.echoed, 3);
    CHECK_EQ(c.collisions, 3);   /* one altered byte per round */
}

static void test_check_silent_line(void)
{
    fap_port_check c;
    int rc;
    run_check(0, 1, &c, &rc);
    CHECK_EQ(rc, 0);
    CHECK_EQ(c.rounds, 3);
    CHECK_EQ(c.echoed, 0);
}

static void test_check_bad_arguments(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port *p = open_none(t.name, 1);
    MUST(p != NULL);
    fap_port_check c;
    CHECK_EQ(fap_port_check_direction(p, "x", 1, 1, 10, &c), -EINVAL);   /* echo suppression */
    fap_port_close(p);
    p = open_none(t.name, 0);
    MUST(p != NULL);
    CHECK_EQ(fap_port_check_direction(p, "x", 0, 1, 10, &c), -EINVAL);
    CHECK_EQ(fap_port_check_direction(p, NULL, 1, 1, 10, &c), -EINVAL);
    CHECK_EQ(fap_port_check_direction(p, "x", 1, FAP_PORT_CHECK_MAX_ROUNDS + 1, 10, &c), -EINVAL);
    CHECK_EQ(fap_port_check_direction(p, "x", 1, 1, 10, NULL), -EINVAL);
    CHECK_EQ(fap_port_check_direction(NULL, "x", 1, 1, 10, &c), -EINVAL);
    fap_port_close(p);
    tp_close(&t);
}

UNIT_MAIN(UNIT(test_check_echoing_pty), UNIT(test_check_counts_collisions),
          UNIT(test_check_silent_line), UNIT(test_check_bad_arguments))
