/* bench_fapx_c - the C side of bench/fap_py/bench_fap_py.py: the same FAP
 * exchanges the Python benchmark runs through fap_py, run through libfap's
 * handle API (fapx.h) directly, so the difference is the binding's cost.
 *
 * usage: bench_fapx_c MASTER_PATH SLAVE_PATH MODE COUNT SIZE
 *   rt      master sends SIZE bytes to slave 1, a thread on the slave echoes
 *           them back, the master waits for the echo; COUNT times.
 *   stream  master queues COUNT messages for slave 1 (waiting for room in
 *           its tx queue, at most WINDOW ahead of the receiver); the slave
 *           thread receives them all.
 *   calls   no wire: COUNT x fapx_tx into a deep queue plus COUNT x fapx_rx
 *           on an empty queue, on a slave handle no master polls.
 * Prints one line: "mode=.. count=.. size=.. wall_s=.. cpu_s=.. received=.."
 * where cpu_s is this process's user+system time (every thread: engines
 * included), received what the slave got (stream: an overloaded,
 * unpaced virtual bus drops bytes a slow reader does not take) and polls
 * the master's SEND_DATA turns over the window (0 in calls mode). */
#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include "fapx.h"

/* FAP has no flow control and the unpaced virtual bus drops what a slow
 * reader leaves (64 KiB per port): the stream keeps at most WINDOW messages
 * between the master's send and the slave's receive, so a run measures
 * speed, not scheduling luck. Same value in bench_fap_py.py. */
#define WINDOW 32

static double cpu_s(void)
{
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return (double)ru.ru_utime.tv_sec + ru.ru_utime.tv_usec / 1e6 +
           (double)ru.ru_stime.tv_sec + ru.ru_stime.tv_usec / 1e6;
}

static double wall_s(void)
{
    return (double)fap_port_now_ns() / 1e9;
}

static void die(const char *what, int rc)
{
    fprintf(stderr, "bench_fapx_c: %s: %s\n", what, fapx_strerror(rc));
    exit(1);
}

struct echo_arg {
    fapx *slave;
    long count;
    int echo;              /* 1: send each message back to its sender */
    pthread_mutex_t lock;
    pthread_cond_t cond;
    long received;         /* under lock: the stream window's feedback */
};

static void *slave_thread(void *p)
{
    struct echo_arg *a = p;
    static unsigned char buf[FAPX_MAX_DATA];
    for (long i = 0; i < a->count; i++) {
        unsigned src;
        /* stream: frames the bus lost never come; stop after 2 s of silence */
        int n = fapx_rx_wait(a->slave, buf, sizeof buf, &src, a->echo ? 10000 : 2000);
        if (n == -ETIMEDOUT && !a->echo)
            break;
        if (n < 0)
            die("slave rx", n);
        if (a->echo) {       /* the echo first: the count is the bench's, not the round trip's */
            int rc = fapx_tx_wait(a->slave, src, buf, (size_t)n, -1);
            if (rc < 0)
                die("slave tx", rc);
        }
        pthread_mutex_lock(&a->lock);
        a->received++;
        pthread_cond_signal(&a->cond);
        pthread_mutex_unlock(&a->lock);
    }
    return NULL;
}

static fapx *open_node(const char *path, unsigned mode, unsigned id)
{
    fapx_options o;
    fapx_options_init(&o);
    o.mode = mode;
    o.id = id;
    fapx *h;
    int rc = fapx_open(&h, path, &o);
    if (rc < 0)
        die(path, rc);
    return h;
}

int main(int argc, char **argv)
{
    if (argc != 6) {
        fprintf(stderr, "usage: %s MASTER_PATH SLAVE_PATH rt|stream|calls COUNT SIZE\n", argv[0]);
        return 2;
    }
    const char *mode = argv[3];
    long count = atol(argv[4]);
    size_t size = (size_t)atol(argv[5]);
    if (count <= 0 || size < 1 || size > FAPX_MAX_DATA) {
        fprintf(stderr, "bench_fapx_c: bad COUNT or SIZE\n");
        return 2;
    }
    unsigned char *data = malloc(FAPX_MAX_DATA), *back = malloc(FAPX_MAX_DATA);
    for (size_t i = 0; i < FAPX_MAX_DATA; i++)
        data[i] = (unsigned char)(i * 7);
    double w0, c0, w1, c1;
    long received = count;
    fapx_stats st0, st1;          /* the master's: poll cycles per message */
    memset(&st0, 0, sizeof st0);
    memset(&st1, 0, sizeof st1);

    if (strcmp(mode, "calls") == 0) {
        fapx_options o;
        fapx_options_init(&o);
        o.mode = FAPX_SLAVE;
        o.id = 1;
        o.tx_depth = (unsigned)count;
        fapx *s;
        int rc = fapx_open(&s, argv[2], &o);
        if (rc < 0)
            die(argv[2], rc);
        unsigned src;
        w0 = wall_s();
        c0 = cpu_s();
        for (long i = 0; i < count; i++) {
            if ((rc = fapx_tx(s, 0, data, size)) < 0)
                die("tx", rc);
            if ((rc = fapx_rx(s, back, FAPX_MAX_DATA, &src)) != -EAGAIN)
                die("rx", rc);
        }
        w1 = wall_s();
        c1 = cpu_s();
        fapx_close(s);
    } else {
        int rt = strcmp(mode, "rt") == 0;
        if (!rt && strcmp(mode, "stream") != 0) {
            fprintf(stderr, "bench_fapx_c: unknown mode %s\n", mode);
            return 2;
        }
        fapx *s = open_node(argv[2], FAPX_SLAVE, 1);
        fapx *m = open_node(argv[1], FAPX_MASTER, 0);
        int rc = fapx_add_slave(m, 1);
        if (rc < 0)
            die("add_slave", rc);
        fapx_event ev;
        while (fapx_slave_active(m, 1) != 1)   /* wait for the first ID answer */
            if ((rc = fapx_event_wait(m, &ev, 5000)) < 0)
                die("wait active", rc);
        struct echo_arg arg = { .slave = s, .count = count, .echo = rt };
        pthread_mutex_init(&arg.lock, NULL);
        pthread_cond_init(&arg.cond, NULL);
        pthread_t th;
        fapx_get_stats(m, &st0);
        w0 = wall_s();
        c0 = cpu_s();
        pthread_create(&th, NULL, slave_thread, &arg);
        for (long i = 0; i < count; i++) {
            if (!rt) {
                pthread_mutex_lock(&arg.lock);
                while (i - arg.received >= WINDOW) {
                    struct timespec ts;      /* 2 s without progress: frames were lost */
                    clock_gettime(CLOCK_REALTIME, &ts);
                    ts.tv_sec += 2;
                    if (pthread_cond_timedwait(&arg.cond, &arg.lock, &ts) == ETIMEDOUT)
                        break;
                }
                pthread_mutex_unlock(&arg.lock);
            }
            if ((rc = fapx_tx_wait(m, 1, data, size, -1)) < 0)
                die("master tx", rc);
            if (rt) {
                unsigned src;
                int n = fapx_rx_wait(m, back, FAPX_MAX_DATA, &src, 10000);
                if (n != (int)size || src != 1)
                    die("master rx", n < 0 ? n : -EPROTO);
            }
        }
        pthread_join(th, NULL);
        w1 = wall_s();
        c1 = cpu_s();
        fapx_get_stats(m, &st1);
        received = arg.received;
        if (received < count)     /* the 2 s of silence are not transfer time */
            w1 -= 2.0;
        fapx_close(s);
        fapx_close(m);
    }
    printf("mode=%s count=%ld size=%zu wall_s=%.6f cpu_s=%.6f received=%ld polls=%llu\n",
           mode, count, size, w1 - w0, c1 - c0, received,
           (unsigned long long)(st1.polls - st0.polls));
    free(data);
    free(back);
    return 0;
}
