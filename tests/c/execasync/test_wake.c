/* The exec master's reply wait on a bus paced at 115200 (a relay thread
 * delivering each byte at the end of its wire time): how many times the
 * master's thread sleeps per transaction (voluntary context switches,
 * getrusage RUSAGE_THREAD), not how long anything takes. A reply read
 * piece by piece costs 12-14 (the decoder's lower bound: 8 bytes, then 4
 * from inside the data, then per byte); expecting the node's last reply
 * length after the request's end costs 2-4. */
#include <errno.h>
#include <pthread.h>
#include <stdio.h>

#include "exec_async_engine.h"
#include "fap_vbus.h"
#include "unit.h"
#include "wakeups.h"
#include "exec_echo.h"

#define TRANSACTIONS 40
/* well above the 2-4 a reply costs now, well under the 12-14 of per-piece
 * reads: a loaded machine moves it by one or two either way */
#define MAX_WAKEUPS_PER_TRANSACTION 7.0

static void *serve(void *arg)
{
    execSlave *s = arg;
    while (execSlaveServe(s, -1) >= 0)
        ;
    return NULL;
}

static void test_reply_wait_wakeups(void)
{
    fap_vbus *bus = test_paced_bus(115200);
    REQUIRE(bus);
    fap_port_options po;
    fap_port_options_init(&po);
    po.rs485_mode = FAP_RS485_NONE;
    po.baud = 115200;
    execMasterOptions mo;
    execMasterOptionsInit(&mo);
    mo.reply_timeout_us = 1000000;   /* a loaded machine must not cause a retry */
    execMaster *m = NULL;
    REQUIRE(execMasterOpen(&m, fap_vbus_port_path(bus, 0), &po, &mo) == 0);
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    execSlave *s = NULL;
    REQUIRE(execSlaveOpen(&s, fap_vbus_port_path(bus, 1), &po, &so, test_exec_echo, NULL) == 0);
    pthread_t th;
    pthread_create(&th, NULL, serve, s);

    byte reply[64];
    word len = 0;
    /* the first few learn the reply's length and the link's pace */
    for (int i = 0; i < 4; i++)
        CHECK_EQ(execMasterTransact(m, 1, (const byte *)"pingpong", 8, reply, sizeof reply, &len), 0);
    long w0 = test_thread_wakeups();
    int ok = 0;
    for (int i = 0; i < TRANSACTIONS; i++) {
        len = 0;
        int rc = execMasterTransact(m, 1, (const byte *)"pingpong", 8, reply, sizeof reply, &len);
        ok += rc == 0 && len == 8 && memcmp(reply, "pingpong", 8) == 0;
    }
    long w1 = test_thread_wakeups();
    CHECK_EQ(ok, TRANSACTIONS);
    double per = (double)(w1 - w0) / TRANSACTIONS;
    fprintf(stderr, "master wake-ups per transaction at 115200: %.2f\n", per);
    CHECK(w0 >= 0 && per <= MAX_WAKEUPS_PER_TRANSACTION);
    execMasterStats st;
    execMasterGetStats(m, &st);
    CHECK_EQ(st.retries, 0);

    execSlaveStop(s);
    pthread_join(th, NULL);
    execSlaveClose(s);
    execMasterClose(m);
    fap_vbus_close(bus);
}

UNIT_MAIN(UNIT(test_reply_wait_wakeups))
