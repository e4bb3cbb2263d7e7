/* mikroC master and slave on a bus paced at 115200 (a relay thread
 * delivering each byte at the end of its wire time): how many times each
 * side's thread sleeps per exchange (voluntary context switches,
 * getrusage RUSAGE_THREAD), not how long anything takes. Reading the
 * 8-byte frame to the decoder's lower bound, a piece at a time, cost 6-11;
 * expecting a full frame (and, on the master, sleeping until our frame's
 * end plus the reply's wire time) costs 2-4. */
#include <errno.h>
#include <pthread.h>
#include <semaphore.h>
#include <stdio.h>

#include "fap_vbus.h"
#include "mikroc_rs485.h"
#include "unit.h"
#include "wakeups.h"

#define EXCHANGES 40
/* the master: above the 2.3-3.3 an exchange costs it now, under the
 * 5.9-10 of per-piece reads; the slave (no reply bound to sleep on: it
 * holds from a request's first piece) varies more, 3.9-6.1 now against
 * 6-11 before: bounded loosely, as a guard against a per-byte reader */
#define MAX_WAKEUPS 5.0
#define MAX_WAKEUPS_SLAVE 8.0

typedef struct slave_arg {
    const char *path;
    int stop;                   /* atomic */
    sem_t ready;                /* the slave's port is open */
    long wakeups;               /* over the `counted` exchanges after the 5th */
    int served, counted;
} slave_arg;

static void *slave_main(void *arg)
{
    slave_arg *a = arg;
    static mikrocRS485_ctx c;
    mikrocRS485_CtxInitSlave(&c, 1);
    int rc = mikrocRS485_CtxOpen(&c, a->path, 115200, NULL);
    sem_post(&a->ready);
    if (rc < 0)
        return NULL;
    char buf[8];
    memset(buf, 0, sizeof buf);
    long w0 = 0;
    while (!__atomic_load_n(&a->stop, __ATOMIC_ACQUIRE)) {
        int m = mikrocRS485_CtxPoll(&c, buf, 100);
        if (m & MIKROC_RS485_POLL_READY) {
            if (++a->served == 5)
                w0 = test_thread_wakeups();   /* after the pace was learnt */
            int n = (uint8_t)buf[MIKROC_RS485_IDX_COUNT];
            buf[MIKROC_RS485_IDX_READY] = 0;
            mikrocRS485_CtxSend(&c, buf, (unsigned)n, 1);
            if (a->served > 5) {
                a->wakeups = test_thread_wakeups() - w0;
                a->counted = a->served - 5;
            }
        }
        buf[MIKROC_RS485_IDX_ERROR] = 0;
    }
    mikrocRS485_CtxClose(&c);
    return NULL;
}

static void test_exchange_wakeups(void)
{
    fap_vbus *bus = test_paced_bus(115200);
    REQUIRE(bus);
    slave_arg sa = {.path = fap_vbus_port_path(bus, 1)};
    sem_init(&sa.ready, 0, 0);
    pthread_t th;
    pthread_create(&th, NULL, slave_main, &sa);
    sem_wait(&sa.ready);   /* a request sent before the slave listens is lost */
    mikrocRS485_ctx m;
    mikrocRS485_CtxInitMaster(&m);
    REQUIRE(mikrocRS485_CtxOpen(&m, fap_vbus_port_path(bus, 0), 115200, NULL) == 0);
    char rx[8];
    long w0 = 0;
    int ok = 0;
    for (int i = 0; i < 5 + EXCHANGES; i++) {
        if (i == 5)
            w0 = test_thread_wakeups();
        memset(rx, 0, sizeof rx);
        REQUIRE(mikrocRS485_CtxSend(&m, "abc", 3, 1) == 0);
        int r = mikrocRS485_CtxPoll(&m, rx, 2000);
        ok += i >= 5 && (r & MIKROC_RS485_POLL_READY) && memcmp(rx, "abc", 3) == 0;
    }
    double per = (double)(test_thread_wakeups() - w0) / EXCHANGES;
    __atomic_store_n(&sa.stop, 1, __ATOMIC_RELEASE);
    pthread_join(th, NULL);
    double sper = sa.counted ? (double)sa.wakeups / sa.counted : 0;
    fprintf(stderr, "wake-ups per exchange at 115200: master %.2f, slave %.2f\n", per, sper);
    CHECK_EQ(ok, EXCHANGES);
    CHECK(per <= MAX_WAKEUPS);
    CHECK(sa.counted >= EXCHANGES - 1 && sa.wakeups > 0 && sper <= MAX_WAKEUPS_SLAVE);
    sem_destroy(&sa.ready);
    mikrocRS485_CtxClose(&m);
    fap_vbus_close(bus);
}

UNIT_MAIN(UNIT(test_exchange_wakeups))
