/* The classic vendor API over the default handle: every documented return
 * code, before and after fapInit/fapConfig, and real data with a slave. */
#include "fap.h"
#include "bus_util.h"
#include <poll.h>
#include <pthread.h>
#include <stdint.h>

static fap_vbus *bus;
static fapx *peer;                    /* a handle-API slave 1 on port 1 */

/* Wait (poll on the notify fd, no sleeping) for fapRx to return GOOD. */
static usys rx_wait(u8 *data, usys *size, usys *id, int timeout_ms)
{
    fapx *h = fapClassicHandle();
    int64_t end = fap_port_now_ns() + (int64_t)timeout_ms * 1000000;
    for (;;) {
        usys rc = fapRx(data, size, id);
        if (rc != E_RES || !h)
            return rc;
        int left = (int)((end - fap_port_now_ns()) / 1000000);
        if (left <= 0)
            return E_RES;
        struct pollfd pf = { .fd = fapx_notify_fd(h), .events = POLLIN };
        poll(&pf, 1, left);
    }
}

static void test_before_init(void)
{
    u8 d[MAX_DATA_SIZE];
    usys size, id;
    fapT c = { .id = 0, .mode = FAP_MASTER, .idcTime = 15 };
    CHECK_EQ(fapConfig(&c), E_INIT);
    CHECK_EQ(fapAddSlave(1), E_INIT);
    CHECK_EQ(fapRemSlave(1), E_INIT);
    CHECK_EQ(fapTx(d, 1, 1), E_INIT);
    CHECK_EQ(fapRx(d, &size, &id), E_INIT);
    CHECK(fapClassicHandle() == NULL);
}

static void test_init_errors(void)
{
    bus = open_bus(4, 0);
    REQUIRE(bus);
    char *path = (char *)fap_vbus_port_path(bus, 0);
    CHECK_EQ(fapInit(NULL, 115200), BAD);
    CHECK_EQ(fapInit(path, 1200), BAD);
    CHECK_EQ(fapInit(path, 230400), BAD);
    CHECK_EQ(fapInit(path, 0), BAD);
    CHECK_EQ(fapInit("/nonexistent/ttyFAP", 115200), BAD);
    CHECK_EQ(fapConfig(NULL), E_INIT);      /* still not initialised */
    fapx_options o;
    fast_options(&o, FAPX_MASTER, 0);
    fapClassicSetOptions(&o);
    CHECK_EQ(fapInit(path, 115200), GOOD);
    CHECK_EQ(fapInit(path, 115200), E_INIT);
    CHECK_EQ(fapInit((char *)fap_vbus_port_path(bus, 2), 9600), E_INIT);
}

static void test_config_errors(void)
{
    fapT c;
    CHECK_EQ(fapConfig(NULL), E_PARAM);
    c = (fapT){ .id = 0, .mode = 2, .idcTime = 0 };
    CHECK_EQ(fapConfig(&c), E_PARAM);
    c = (fapT){ .id = 3, .mode = FAP_MASTER, .idcTime = 0 };
    CHECK_EQ(fapConfig(&c), E_VALUE);
    c = (fapT){ .id = 0, .mode = FAP_SLAVE, .idcTime = 0 };
    CHECK_EQ(fapConfig(&c), E_VALUE);
    c = (fapT){ .id = 32, .mode = FAP_SLAVE, .idcTime = 0 };
    CHECK_EQ(fapConfig(&c), E_VALUE);
    CHECK(fapClassicHandle() == NULL);      /* nothing started */
}

static void test_between_init_and_config(void)
{
    u8 d[MAX_DATA_SIZE + 1];
    usys size, id;
    memset(d, 0, sizeof d);
    CHECK_EQ(fapRx(d, &size, &id), E_RES);
    CHECK_EQ(fapRx(NULL, &size, &id), E_PARAM);
    CHECK_EQ(fapTx(d, 0, 1), E_VALUE);
    CHECK_EQ(fapTx(d, MAX_DATA_SIZE + 1, 1), E_VALUE);
    CHECK_EQ(fapTx(d, 1, 32), E_VALUE);
    CHECK_EQ(fapTx(NULL, 1, 1), E_VALUE);
    /* fapTx queues: the default depth is 64, then E_RES */
    int good = 0;
    for (int i = 0; i < 70; i++) {
        d[0] = (u8)i;
        usys rc = fapTx(d, 1 + (usys)i, 1);
        if (rc == GOOD)
            good++;
        else
            CHECK_EQ(rc, E_RES);
    }
    CHECK_EQ(good, FAPX_DEFAULT_TX_DEPTH);
}

static void test_master_with_slave(void)
{
    fapx_options o;
    fast_options(&o, FAPX_SLAVE, 1);
    int rc = fapx_open(&peer, fap_vbus_port_path(bus, 1), &o);
    REQUIRE(rc == 0);
    fapT c = { .id = 0, .mode = FAP_MASTER, .idcTime = 0 };
    CHECK_EQ(fapConfig(&c), GOOD);
    REQUIRE(fapClassicHandle() != NULL);
    /* the 64 frames queued before fapConfig arrive at slave 1, in order */
    uint8_t buf[FAPX_MAX_DATA];
    unsigned src;
    int bad = 0;
    for (int i = 0; i < FAPX_DEFAULT_TX_DEPTH; i++) {
        int n = fapx_rx_wait(peer, buf, sizeof buf, &src, 2000);
        if (n != 1 + i || buf[0] != (uint8_t)i || src != 0)
            bad++;
    }
    CHECK_EQ(bad, 0);

    CHECK_EQ(fapAddSlave(0), E_VALUE);
    CHECK_EQ(fapAddSlave(32), E_VALUE);
    CHECK_EQ(fapAddSlave(1), GOOD);
    CHECK_EQ(fapAddSlave(1), E_VALUE);
    CHECK_EQ(fapRemSlave(5), E_VALUE);
    CHECK_EQ(fapRemSlave(0), E_VALUE);
    u8 d[MAX_DATA_SIZE];
    CHECK_EQ(fapTx(d, 1, 0), E_VALUE);      /* master to itself */

    /* slave -> master */
    CHECK_EQ(fapx_tx(peer, 0, "hello master", 12), 0);
    usys size = 0, id = 99;
    CHECK_EQ(rx_wait(d, &size, &id, 2000), GOOD);
    CHECK_EQ(size, 12);
    CHECK_EQ(id, 1);
    CHECK_MEM(d, "hello master", 12);
    CHECK_EQ(fapRx(d, &size, &id), E_RES);
    /* master -> slave, full size */
    for (int i = 0; i < MAX_DATA_SIZE; i++)
        d[i] = (u8)(i * 7);
    CHECK_EQ(fapTx(d, MAX_DATA_SIZE, 1), GOOD);
    CHECK_EQ(fapx_rx_wait(peer, buf, sizeof buf, &src, 2000), MAX_DATA_SIZE);
    CHECK_MEM(buf, d, MAX_DATA_SIZE);
    CHECK_EQ(src, 0);
    CHECK_EQ(fapRemSlave(1), GOOD);
    CHECK_EQ(fapRemSlave(1), E_VALUE);
}


/* fapTx / fapRx from several threads at once (the vendor says they need
 * not be thread-safe; libfap's are): nothing lost, nothing twice. */
#define TX_THREADS 4
#define TX_EACH 40
static void *tx_thread(void *arg)
{
    int t = (int)(intptr_t)arg;
    for (int k = 0; k < TX_EACH; k++) {
        u8 msg[32];
        usys n = (usys)snprintf((char *)msg, sizeof msg, "t%d#%d", t, k);
        while (fapTx(msg, n, 1) == E_RES)
            fapx_flush(fapClassicHandle(), 1000);   /* wait for room, no sleep */
    }
    return NULL;
}

static int rx_counts[TX_THREADS][TX_EACH];
static pthread_mutex_t rx_lock = PTHREAD_MUTEX_INITIALIZER;
static int rx_total;

static void *rx_thread(void *arg)
{
    (void)arg;
    for (;;) {
        pthread_mutex_lock(&rx_lock);
        int done = rx_total >= TX_THREADS * TX_EACH;
        pthread_mutex_unlock(&rx_lock);
        if (done)
            return NULL;
        u8 d[MAX_DATA_SIZE + 1];
        usys size, id;
        if (rx_wait(d, &size, &id, 200) != GOOD)
            continue;
        d[size] = 0;
        int t = -1, k = -1;
        pthread_mutex_lock(&rx_lock);
        if (id == 1 && sscanf((char *)d, "t%d#%d", &t, &k) == 2 && t >= 0 && t < TX_THREADS &&
            k >= 0 && k < TX_EACH)
            rx_counts[t][k]++;
        rx_total++;
        pthread_mutex_unlock(&rx_lock);
    }
}

static void *echo_peer(void *arg)
{
    (void)arg;
    for (int i = 0; i < TX_THREADS * TX_EACH; i++) {
        uint8_t buf[FAPX_MAX_DATA];
        unsigned src;
        int n = fapx_rx_wait(peer, buf, sizeof buf, &src, 5000);
        if (n <= 0)
            return NULL;
        fapx_tx_wait(peer, 0, buf, (size_t)n, 5000);
    }
    return NULL;
}

static void test_threads_share_fapTx_fapRx(void)
{
    CHECK_EQ(fapAddSlave(1), GOOD);
    pthread_t tx[TX_THREADS], rx[2], echo;
    pthread_create(&echo, NULL, echo_peer, NULL);
    for (int i = 0; i < 2; i++)
        pthread_create(&rx[i], NULL, rx_thread, NULL);
    for (int t = 0; t < TX_THREADS; t++)
        pthread_create(&tx[t], NULL, tx_thread, (void *)(intptr_t)t);
    for (int t = 0; t < TX_THREADS; t++)
        pthread_join(tx[t], NULL);
    pthread_join(echo, NULL);
    for (int i = 0; i < 2; i++)
        pthread_join(rx[i], NULL);
    int bad = 0;
    for (int t = 0; t < TX_THREADS; t++)
        for (int k = 0; k < TX_EACH; k++)
            bad += rx_counts[t][k] != 1;
    CHECK_EQ(rx_total, TX_THREADS * TX_EACH);
    CHECK_EQ(bad, 0);
    CHECK_EQ(fapRemSlave(1), GOOD);
}

static void test_reconfigure_as_slave(void)
{
    fapT c = { .id = 5, .mode = FAP_SLAVE, .idcTime = 0 };
    CHECK_EQ(fapConfig(&c), GOOD);
    CHECK_EQ(fapAddSlave(2), E_PARAM);
    CHECK_EQ(fapRemSlave(2), E_PARAM);
    u8 d[4] = { 1, 2, 3, 4 };
    CHECK_EQ(fapTx(d, 4, 5), E_VALUE);      /* slave to itself */
    CHECK_EQ(fapTx(d, 4, 0), GOOD);
}

static void test_close_and_init_again(void)
{
    fapClassicClose();
    u8 d[MAX_DATA_SIZE];
    usys size, id;
    CHECK_EQ(fapTx(d, 1, 1), E_INIT);
    CHECK_EQ(fapRx(d, &size, &id), E_INIT);
    CHECK_EQ(fapAddSlave(1), E_INIT);
    CHECK(fapClassicHandle() == NULL);
    CHECK_EQ(fapInit((char *)fap_vbus_port_path(bus, 0), 57600), GOOD);
    fapClassicClose();
    fapClassicClose();                      /* harmless twice */
    fapClassicSetOptions(NULL);
    fapx_close(peer);
    fap_vbus_close(bus);
}

UNIT_MAIN(UNIT(test_before_init), UNIT(test_init_errors), UNIT(test_config_errors),
          UNIT(test_between_init_and_config), UNIT(test_master_with_slave), UNIT(test_threads_share_fapTx_fapRx),
          UNIT(test_reconfigure_as_slave), UNIT(test_close_and_init_again))
