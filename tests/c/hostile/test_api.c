/* Hostile input for every public C function: NULL, sizes 0/1/1024/1025/
 * huge, IDs 0/31/32/255, calls in the wrong order and after close, huge
 * timeouts. Each call must return its documented code, never crash (the
 * sanitizer builds of CI run this too) and never hang (meson's timeout;
 * every wait below is bounded or woken by another thread). */
#include <errno.h>
#include <limits.h>
#include <pthread.h>
#include <stdint.h>
#include <unistd.h>

#include "exec_async.h"
#include "fap/fapx_internal.h"
#include "exec_async_engine.h"
#include "fap.h"
#include "fapx.h"
#include "fap_port.h"
#include "fap_vbus.h"
#include "mikroc_rs485.h"
#include "unit.h"
#include "exec_echo.h"

#define HUGE_SIZE ((size_t)SIZE_MAX)

static fap_vbus *open_bus(unsigned n)
{
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    bo.n_ports = n;
    fap_vbus *b = NULL;
    return fap_vbus_open(&b, &bo) == 0 ? b : NULL;
}

static void quick_port(fap_port_options *po)
{
    fap_port_options_init(po);
    po->rs485_mode = FAP_RS485_NONE;
}

/* ---- fap_port.h ---- */
static void test_port(void)
{
    fap_port_options po;
    quick_port(&po);
    fap_port *p = (fap_port *)0x1;
    CHECK(fap_port_open(NULL, "/dev/null", &po) < 0);
    CHECK(fap_port_open(&p, NULL, &po) < 0);
    CHECK(p == (fap_port *)0x1);                     /* *out set only on success */
    CHECK(fap_port_open(&p, "/nonexistent/tty", &po) == -ENOENT);
    CHECK(fap_port_open(&p, "", &po) < 0);
    fap_vbus *b = open_bus(2);
    REQUIRE(b);
    po.baud = 12345;                                 /* no termios rate */
    CHECK_EQ(fap_port_open(&p, fap_vbus_port_path(b, 0), &po), -EINVAL);
    po.baud = UINT_MAX;
    CHECK_EQ(fap_port_open(&p, fap_vbus_port_path(b, 0), &po), -EINVAL);
    po.baud = 0;
    CHECK(fap_port_open(&p, fap_vbus_port_path(b, 0), &po) < 0);
    quick_port(&po);
    po.rs485_mode = (fap_rs485_mode)99;
    CHECK(fap_port_open(&p, fap_vbus_port_path(b, 0), &po) < 0);
    quick_port(&po);
    CHECK(fap_port_open(&p, fap_vbus_port_path(b, 0), NULL) == 0);   /* NULL = defaults */
    fap_port_close(p);
    fap_port *a = NULL, *c = NULL;
    REQUIRE(fap_port_open(&a, fap_vbus_port_path(b, 0), &po) == 0);
    REQUIRE(fap_port_open(&c, fap_vbus_port_path(b, 1), &po) == 0);
    /* NULL handle everywhere */
    fap_port_close(NULL);
    CHECK(fap_port_reopen(NULL) < 0);
    CHECK_EQ(fap_port_fd(NULL), -1);
    CHECK(fap_port_write(NULL, "x", 1) < 0);
    char buf[2048];
    CHECK(fap_port_read(NULL, buf, 1, 0) < 0);
    CHECK(fap_port_flush(NULL) < 0);
    CHECK(fap_port_discard_input(NULL) < 0);
    CHECK(fap_port_send(NULL, "x", 1) < 0);
    CHECK(fap_port_transact(NULL, "x", 1, buf, sizeof buf, 0) < 0);
    CHECK(fap_port_transact(a, NULL, 5, buf, sizeof buf, 0) < 0);    /* NULL request, n > 0 */
    CHECK(fap_port_transact(a, "x", 1, NULL, 5, 0) < 0);             /* NULL reply, cap > 0 */
    CHECK_EQ(fap_port_discard_input(a), 0);
    fap_port_get_stats(NULL, NULL);
    fap_port_stats ps;
    fap_port_get_stats(NULL, &ps);
    fap_port_get_stats(a, NULL);
    CHECK(fap_port_kernel_rs485(NULL, NULL, NULL, NULL) < 0);
    CHECK_EQ(fap_port_kernel_rs485(a, NULL, NULL, NULL), -ENOTTY);
    CHECK(fap_port_strerror(0) != NULL);
    CHECK(fap_rs485_mode_name((fap_rs485_mode)-1) != NULL);
    /* NULL buffers, sizes 0 / 1024 / 1025 / huge */
    CHECK(fap_port_write(a, NULL, 5) < 0);
    CHECK_EQ(fap_port_write(a, NULL, 0), 0);
    CHECK_EQ(fap_port_write(a, buf, 0), 0);
    CHECK(fap_port_read(a, NULL, 5, 0) < 0);
    CHECK_EQ(fap_port_read(a, buf, 0, 0), 0);
    memset(buf, 0x55, sizeof buf);
    CHECK_EQ(fap_port_write(a, buf, 1024), 1024);
    CHECK_EQ(fap_port_write(a, buf, 1025), 1025);
    size_t got = 0;
    int64_t end = fap_port_now_ns() + 5000000000LL;
    while (got < 2049) {
        ssize_t r = fap_port_read(c, buf, sizeof buf, end);
        if (r <= 0)
            break;
        got += (size_t)r;
    }
    CHECK_EQ(got, 2049);
    /* huge: a count no buffer has must be refused, not read past the end */
    CHECK(fap_port_write(a, buf, HUGE_SIZE) < 0);
    /* deadlines: 0 = do not wait, in the past = do not wait, INT64_MIN too */
    CHECK_EQ(fap_port_read(c, buf, 1, 0), 0);
    CHECK_EQ(fap_port_read(c, buf, 1, 1), 0);
    CHECK_EQ(fap_port_read(c, buf, 1, INT64_MIN), 0);
    /* INT64_MAX = forever: returns as soon as a byte comes */
    CHECK_EQ(fap_port_write(a, "z", 1), 1);
    CHECK_EQ(fap_port_read(c, buf, sizeof buf, INT64_MAX), 1);
    fap_port_close(a);
    fap_port_close(c);
    fap_vbus_close(b);
}

/* ---- fap_vbus.h ---- */
static void test_vbus(void)
{
    fap_vbus *b = (fap_vbus *)0x1;
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    CHECK(fap_vbus_open(NULL, &bo) < 0);
    bo.n_ports = 0;
    CHECK_EQ(fap_vbus_open(&b, &bo), -EINVAL);
    bo.n_ports = 1;
    CHECK_EQ(fap_vbus_open(&b, &bo), -EINVAL);
    bo.n_ports = FAP_VBUS_MAX_PORTS + 1;
    CHECK_EQ(fap_vbus_open(&b, &bo), -EINVAL);
    bo.n_ports = UINT_MAX;
    CHECK_EQ(fap_vbus_open(&b, &bo), -EINVAL);
    CHECK(b == (fap_vbus *)0x1);
    fap_vbus_close(NULL);
    CHECK_EQ(fap_vbus_port_count(NULL), 0);
    CHECK(fap_vbus_port_path(NULL, 0) == NULL);
    CHECK(fap_vbus_set_fault(NULL, 0, 0.1, 0.1) < 0);
    CHECK(fap_vbus_drop_next(NULL, 0, 1) < 0);
    CHECK(fap_vbus_corrupt_next(NULL, 0, 1) < 0);
    CHECK(fap_vbus_silence(NULL, 0, 1) < 0);
    CHECK(fap_vbus_disconnect(NULL, 0, 1) < 0);
    fap_vbus_stats vs;
    fap_vbus_get_stats(NULL, &vs);
    b = open_bus(2);
    REQUIRE(b);
    fap_vbus_get_stats(b, NULL);
    CHECK(fap_vbus_port_path(b, 2) == NULL);
    CHECK(fap_vbus_port_path(b, UINT_MAX) == NULL);
    CHECK_EQ(fap_vbus_set_fault(b, 2, 0.1, 0.1), -EINVAL);
    CHECK_EQ(fap_vbus_set_fault(b, -2, 0.1, 0.1), -EINVAL);
    CHECK_EQ(fap_vbus_set_fault(b, 0, -0.5, 0), -EINVAL);
    CHECK_EQ(fap_vbus_set_fault(b, 0, 1.5, 0), -EINVAL);
    CHECK_EQ(fap_vbus_set_fault(b, 0, 0, 0.0 / 0.0), -EINVAL);   /* NaN */
    CHECK_EQ(fap_vbus_set_fault(b, 0, 1.0 / 0.0, 0), -EINVAL);   /* inf */
    CHECK_EQ(fap_vbus_set_fault(b, -1, 0, 0), 0);
    CHECK_EQ(fap_vbus_drop_next(b, 5, 1), -EINVAL);
    CHECK_EQ(fap_vbus_corrupt_next(b, 5, 1), -EINVAL);
    CHECK_EQ(fap_vbus_silence(b, 5, 1), -EINVAL);
    CHECK_EQ(fap_vbus_disconnect(b, 5, 1), -EINVAL);
    CHECK_EQ(fap_vbus_drop_next(b, 0, UINT_MAX), 0);
    CHECK_EQ(fap_vbus_silence(b, 0, UINT_MAX), 0);               /* huge: no overflow */
    fap_vbus_close(b);
}

/* ---- fapx.h ---- */
typedef struct waiter { fapx *h; int rc; } waiter;

static void *rx_forever(void *arg)
{
    waiter *w = arg;
    char buf[8];
    __atomic_store_n(&w->rc, fapx_rx_wait(w->h, buf, sizeof buf, NULL, INT_MAX), __ATOMIC_RELEASE);
    return NULL;
}

static void test_fapx(void)
{
    fapx_options o;
    fapx_options_init(&o);
    o.port.rs485_mode = FAP_RS485_NONE;
    fapx *h = (fapx *)0x1;
    CHECK_EQ(fapx_open(NULL, "/dev/null", &o), -EINVAL);
    CHECK_EQ(fapx_open(&h, NULL, &o), -EINVAL);
    CHECK(fapx_open(&h, "/nonexistent", &o) < 0);
    fap_vbus *b = open_bus(3);
    REQUIRE(b);
    const char *p0 = fap_vbus_port_path(b, 0);
    CHECK_EQ(fapx_open(&h, p0, NULL), -EINVAL);
    o.mode = 2;
    CHECK_EQ(fapx_open(&h, p0, &o), -EINVAL);
    o.mode = FAPX_MASTER;
    o.id = 1;                                         /* the master is 0 */
    CHECK_EQ(fapx_open(&h, p0, &o), -EINVAL);
    o.mode = FAPX_SLAVE;
    const unsigned bad_ids[] = {0, 32, 255, UINT_MAX};
    for (size_t i = 0; i < 4; i++) {
        o.id = bad_ids[i];
        CHECK_EQ(fapx_open(&h, p0, &o), -EINVAL);
    }
    o.mode = FAPX_MASTER;
    o.id = 0;
    o.rx_depth = UINT_MAX;
    CHECK_EQ(fapx_open(&h, p0, &o), -EINVAL);
    o.rx_depth = 0;
    CHECK(h == (fapx *)0x1);
    /* NULL handle */
    fapx_close(NULL);
    CHECK_EQ(fapx_add_slave(NULL, 1), -EINVAL);
    CHECK_EQ(fapx_remove_slave(NULL, 1), -EINVAL);
    CHECK_EQ(fapx_slave_active(NULL, 1), -EINVAL);
    CHECK_EQ(fapx_listed_mask(NULL), 0);
    CHECK_EQ(fapx_active_mask(NULL), 0);
    CHECK_EQ(fapx_tx(NULL, 1, "x", 1), -EINVAL);
    CHECK_EQ(fapx_tx_wait(NULL, 1, "x", 1, 0), -EINVAL);
    CHECK_EQ(fapx_flush(NULL, 0), -EINVAL);
    char buf[2048];
    CHECK_EQ(fapx_rx(NULL, buf, sizeof buf, NULL), -EINVAL);
    CHECK_EQ(fapx_rx_wait(NULL, buf, sizeof buf, NULL, 0), -EINVAL);
    fapx_event ev;
    CHECK_EQ(fapx_event_get(NULL, &ev), -EINVAL);
    CHECK_EQ(fapx_event_wait(NULL, &ev, 0), -EINVAL);
    CHECK(fapx_notify_fd(NULL) < 0);
    fapx_set_callback(NULL, NULL, NULL);
    fapx_stats st;
    fapx_get_stats(NULL, &st);
    CHECK_EQ(fapx_rx_pending(NULL), 0);
    CHECK_EQ(fapx_tx_pending(NULL), 0);
    CHECK(fapx_port(NULL) == NULL);
    CHECK(fapx_event_name(-1) != NULL);
    CHECK(fapx_event_name(INT_MAX) != NULL);
    fapx_options_init(NULL);
    CHECK(fapx_options_port(NULL) == NULL);

    fapx_options_init(&o);
    o.port.rs485_mode = FAP_RS485_NONE;
    o.idc_us = 100000;
    o.id_answer_us = 2000;
    REQUIRE(fapx_open(&h, p0, &o) == 0);
    fapx_get_stats(h, NULL);
    CHECK_EQ(fapx_event_get(h, NULL), -EINVAL);
    /* IDs 0/31/32/255 */
    CHECK_EQ(fapx_add_slave(h, 0), -EINVAL);
    CHECK_EQ(fapx_add_slave(h, 32), -EINVAL);
    CHECK_EQ(fapx_add_slave(h, 255), -EINVAL);
    CHECK_EQ(fapx_add_slave(h, UINT_MAX), -EINVAL);
    CHECK_EQ(fapx_add_slave(h, 31), 0);
    CHECK_EQ(fapx_add_slave(h, 31), -EEXIST);
    CHECK_EQ(fapx_slave_active(h, 32), -EINVAL);
    CHECK_EQ(fapx_slave_active(h, 30), -ENOENT);
    CHECK_EQ(fapx_remove_slave(h, 30), -ENOENT);
    CHECK_EQ(fapx_remove_slave(h, 32), -EINVAL);
    CHECK_EQ(fapx_remove_slave(h, 31), 0);
    CHECK_EQ(fapx_remove_slave(h, 31), -ENOENT);
    /* sizes 0 / 1024 / 1025 / huge, NULL data, bad destinations */
    memset(buf, 0x10, sizeof buf);
    CHECK_EQ(fapx_tx(h, 1, buf, 0), -EINVAL);
    CHECK_EQ(fapx_tx(h, 1, NULL, 4), -EINVAL);
    CHECK_EQ(fapx_tx(h, 1, buf, 1025), -EINVAL);
    CHECK_EQ(fapx_tx(h, 1, buf, HUGE_SIZE), -EINVAL);
    CHECK_EQ(fapx_tx(h, 0, buf, 4), -EINVAL);       /* the master to itself */
    CHECK_EQ(fapx_tx(h, 32, buf, 4), -EINVAL);
    CHECK_EQ(fapx_tx(h, 255, buf, 4), -EINVAL);
    CHECK_EQ(fapx_tx(h, 31, buf, 1024), 0);
    CHECK_EQ(fapx_tx_wait(h, 31, buf, 1025, 0), -EINVAL);
    CHECK_EQ(fapx_flush(h, 10000), 0);
    CHECK_EQ(fapx_rx(h, buf, sizeof buf, NULL), -EAGAIN);
    CHECK_EQ(fapx_rx(h, NULL, 10, NULL), -EINVAL);
    CHECK_EQ(fapx_rx_wait(h, buf, sizeof buf, NULL, 0), -ETIMEDOUT);
    CHECK_EQ(fapx_rx_wait(h, buf, sizeof buf, NULL, 1), -ETIMEDOUT);
    CHECK_EQ(fapx_event_wait(h, &ev, 1), -ETIMEDOUT);
    /* a slave handle: slave-list calls are refused */
    fapx_options so;
    fapx_options_init(&so);
    so.mode = FAPX_SLAVE;
    so.id = 31;
    so.port.rs485_mode = FAP_RS485_NONE;
    fapx *s = NULL;
    REQUIRE(fapx_open(&s, fap_vbus_port_path(b, 1), &so) == 0);
    CHECK_EQ(fapx_add_slave(s, 1), -EPERM);
    CHECK_EQ(fapx_remove_slave(s, 1), -EPERM);
    CHECK_EQ(fapx_slave_active(s, 1), -EPERM);
    CHECK_EQ(fapx_tx(s, 31, buf, 1), -EINVAL);      /* to itself */
    CHECK_EQ(fapx_tx(s, 32, buf, 1), -EINVAL);
    CHECK_EQ(fapx_tx(s, 0, buf, 1), 0);
    fapx_close(s);
    /* a huge timeout (INT_MAX ms) is no busy loop and no overflow: close
     * wakes it with -ESHUTDOWN */
    waiter w = {.h = h, .rc = 1};
    pthread_t t;
    pthread_create(&t, NULL, rx_forever, &w);
    /* close only once it is inside the wait (the handle's waiter count,
     * internal): a call that starts after close would use a freed handle */
    for (int i = 0; i < 10000; i++) {
        pthread_mutex_lock(&h->lock);
        unsigned in_wait = h->waiters;
        pthread_mutex_unlock(&h->lock);
        if (in_wait)
            break;
        usleep(1000);
    }
    fapx_close(h);
    pthread_join(t, NULL);
    CHECK_EQ(w.rc, -ESHUTDOWN);
    fap_vbus_close(b);
}

/* ---- fap.h (the classic API, wrong order and after close) ---- */
static void test_classic(void)
{
    u8 data[MAX_DATA_SIZE + 1] = {0};
    usys size = 0, id = 0;
    fapT cfg = {.id = 0, .mode = FAP_MASTER, .idcTime = 1};
    /* before fapInit: E_INIT */
    CHECK_EQ(fapConfig(&cfg), E_INIT);
    CHECK_EQ(fapAddSlave(1), E_INIT);
    CHECK_EQ(fapRemSlave(1), E_INIT);
    CHECK_EQ(fapTx(data, 1, 1), E_INIT);
    CHECK_EQ(fapRx(data, &size, &id), E_INIT);
    CHECK_EQ(fapInit(NULL, 115200), BAD);
    fap_vbus *b = open_bus(2);
    REQUIRE(b);
    char *path = (char *)fap_vbus_port_path(b, 0);
    CHECK_EQ(fapInit(path, 0), BAD);
    CHECK_EQ(fapInit(path, 12345), BAD);
    CHECK_EQ(fapInit(path, UINT_MAX), BAD);
    fapx_options o;
    fapx_options_init(&o);
    o.port.rs485_mode = FAP_RS485_NONE;
    o.id_answer_us = 2000;
    fapClassicSetOptions(&o);
    REQUIRE(fapInit(path, 115200) == GOOD);
    CHECK(fapInit(path, 115200) != GOOD);           /* twice */
    CHECK_EQ(fapConfig(NULL), E_PARAM);
    fapT bad = {.id = 0, .mode = 7};
    CHECK_EQ(fapConfig(&bad), E_PARAM);
    bad.mode = FAP_MASTER;
    bad.id = 3;
    CHECK_EQ(fapConfig(&bad), E_VALUE);
    bad.mode = FAP_SLAVE;
    bad.id = 0;
    CHECK_EQ(fapConfig(&bad), E_VALUE);
    bad.id = 32;
    CHECK_EQ(fapConfig(&bad), E_VALUE);
    cfg.idcTime = UINT_MAX;                          /* huge: no overflow */
    REQUIRE(fapConfig(&cfg) == GOOD);
    CHECK_EQ(fapAddSlave(0), E_VALUE);
    CHECK_EQ(fapAddSlave(32), E_VALUE);
    CHECK_EQ(fapAddSlave(255), E_VALUE);
    CHECK_EQ(fapAddSlave(31), GOOD);
    CHECK_EQ(fapAddSlave(31), E_VALUE);
    CHECK_EQ(fapRemSlave(30), E_VALUE);
    CHECK_EQ(fapTx(NULL, 1, 1), E_VALUE);
    CHECK_EQ(fapTx(data, 0, 1), E_VALUE);
    CHECK_EQ(fapTx(data, MAX_DATA_SIZE + 1, 1), E_VALUE);
    CHECK_EQ(fapTx(data, UINT_MAX, 1), E_VALUE);
    CHECK_EQ(fapTx(data, 1, 32), E_VALUE);
    CHECK_EQ(fapTx(data, MAX_DATA_SIZE, 31), GOOD);
    CHECK_EQ(fapRx(NULL, &size, &id), E_PARAM);
    CHECK_EQ(fapRx(data, NULL, &id), E_PARAM);
    CHECK_EQ(fapRx(data, &size, NULL), E_PARAM);
    CHECK_EQ(fapRx(data, &size, &id), E_RES);       /* nothing received */
    fapClassicClose();
    fapClassicClose();                               /* twice */
    /* after close: E_INIT again */
    CHECK_EQ(fapTx(data, 1, 1), E_INIT);
    CHECK_EQ(fapRx(data, &size, &id), E_INIT);
    CHECK_EQ(fapAddSlave(1), E_INIT);
    CHECK_EQ(fapConfig(&cfg), E_INIT);
    CHECK(fapClassicHandle() == NULL);
    fapClassicSetOptions(NULL);
    fap_vbus_close(b);
}

/* ---- exec_async.h: codec and packing ---- */
static void test_exec_codec(void)
{
    byte raw[256], tx[EXEC_ASYNC_MAX_FRAME];
    memset(raw, EXEC_ASYNC_DLE, sizeof raw);
    /* largest frame: 255 DLEs -> exactly 2*255+8 bytes, nothing past it */
    CHECK_EQ(execAsyncBufferOut(1, raw, tx, 255, 0), EXEC_ASYNC_MAX_FRAME);
    CHECK_EQ(execAsyncBufferOut(255, raw, tx, 0, 255), 8);
    CHECK_EQ(execAsyncBufferOut(0, NULL, tx, 0, 0), 8);   /* no data: Raw unused */
    /* byte-in with a buffer of 1 (BufferSize 1): overflow reported, no write past */
    struct execAsyncStateDef st;
    memset(&st, 0, sizeof st);
    st.BufferSize = 1;
    byte small[1];
    int outcome = -1;
    word n = execAsyncBufferOut(3, raw, tx, 5, 9);
    for (word i = 0; i < n; i++)
        if (execAsyncByteIn(tx[i], &st, small))
            outcome = st.Status;
    CHECK_EQ(outcome, EXEC_ASYNC_OVERFLOW);
    /* NULL descriptors are the caller's bug (vendor prototypes); an empty
     * one packs nothing */
    static struct execStructDef VCONST empty[] = {{0, 0, 0}};
    CHECK_EQ(execPackDataEx(raw, raw, empty), 0);
    CHECK_EQ(execUnPackDataEx(raw, raw, empty), 0);
    /* sizes that do not fit a word: 0 (documented), Wide gives the size */
    static struct execStructDef VCONST huge[] = {{0, 65535, 65535}, {0, 0, 0}};
    CHECK_EQ(execPackDataEx(NULL, NULL, huge), 0);     /* refused before touching memory */
    CHECK_EQ(execUnPackDataEx(NULL, NULL, huge), 0);
    CHECK_EQ(execPackData(NULL, huge), 0);
    CHECK_EQ(execUnPackData(NULL, huge), 0);
    static struct execStructDef VCONST overlapping[] = {{4, 2, 1}, {0, 2, 1}, {8, 0, 0}};
    CHECK_EQ(execPackData(raw, overlapping), 0);       /* not ascending: refused */
    CHECK_EQ(execUnPackData(raw, overlapping), 0);
}

static void *serve_forever(void *arg)
{
    execSlave *s = arg;
    while (execSlaveServe(s, INT_MAX) >= 0)          /* huge timeout: Stop ends it */
        ;
    return NULL;
}

static void test_exec_engine(void)
{
    fap_port_options po;
    quick_port(&po);
    execMaster *m = (execMaster *)0x1;
    execSlave *s = (execSlave *)0x1;
    CHECK_EQ(execMasterOpen(NULL, "/dev/null", &po, NULL), -EINVAL);
    CHECK_EQ(execMasterOpen(&m, NULL, &po, NULL), -EINVAL);
    CHECK(execMasterOpen(&m, "/nonexistent", &po, NULL) < 0);
    CHECK(m == (execMaster *)0x1);
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    CHECK(execSlaveOpen(NULL, "/dev/null", &po, &so, test_exec_echo, NULL) < 0);
    CHECK(execSlaveOpen(&s, NULL, &po, &so, test_exec_echo, NULL) < 0);
    CHECK(s == (execSlave *)0x1);
    execMasterOptionsInit(NULL);
    execSlaveOptionsInit(NULL);
    /* NULL handles */
    CHECK_EQ(execMasterSetTimeout(NULL, 1, 1), -EINVAL);
    CHECK_EQ(execMasterTransact(NULL, 1, NULL, 0, NULL, 0, NULL), -EINVAL);
    {
        int64_t dl = 0;
        word rl = 0;
        byte rb[4];
        CHECK(execMasterBegin(NULL, 1, NULL, 0, &dl) < 0);
        CHECK(execMasterStep(NULL, rb, sizeof rb, &rl, &dl) < 0);
        execMasterAbort(NULL);   /* no-op, no crash */
    }
    CHECK_EQ(execMasterBroadcast(NULL, NULL, 0), -EINVAL);
    CHECK_EQ(execMasterNextSeq(NULL, 1), -EINVAL);
    execMasterResetSequence(NULL);
    execMasterStats ms;
    execMasterGetStats(NULL, &ms);
    CHECK(execMasterPort(NULL) == NULL);
    execMasterClose(NULL);
    CHECK(execSlaveServe(NULL, 0) < 0);
    execSlaveStop(NULL);
    execSlaveStats ss;
    execSlaveGetStats(NULL, &ss);
    CHECK(execSlavePort(NULL) == NULL);
    execSlaveClose(NULL);

    fap_vbus *b = open_bus(2);
    REQUIRE(b);
    REQUIRE(execMasterOpen(&m, fap_vbus_port_path(b, 0), &po, NULL) == 0);
    const byte bad_nodes[] = {0, 255};
    for (int i = 0; i < 2; i++) {
        so.node = bad_nodes[i];
        execSlave *x = (execSlave *)0x1;
        CHECK_EQ(execSlaveOpen(&x, fap_vbus_port_path(b, 1), &po, &so, test_exec_echo, NULL), -EINVAL);
        CHECK(x == (execSlave *)0x1);
    }
    so.node = 7;
    CHECK_EQ(execSlaveOpen(&s, fap_vbus_port_path(b, 1), &po, &so, NULL, NULL), -EINVAL);
    REQUIRE(execSlaveOpen(&s, fap_vbus_port_path(b, 1), &po, &so, test_exec_echo, NULL) == 0);
    execMasterGetStats(m, NULL);
    execSlaveGetStats(s, NULL);
    pthread_t t;
    pthread_create(&t, NULL, serve_forever, s);
    byte big[1025] = {0}, reply[300];
    word rlen = 0;
    CHECK_EQ(execMasterTransact(m, 0, big, 1, reply, sizeof reply, &rlen), -EINVAL);
    CHECK_EQ(execMasterTransact(m, 255, big, 1, reply, sizeof reply, &rlen), -EINVAL);
    CHECK_EQ(execMasterTransact(m, 7, NULL, 3, reply, sizeof reply, &rlen), -EINVAL);
    CHECK_EQ(execMasterTransact(m, 7, big, 1, NULL, 5, &rlen), -EINVAL);
    CHECK_EQ(execMasterTransact(m, 7, big, 256, reply, sizeof reply, &rlen), -EMSGSIZE);
    CHECK_EQ(execMasterTransact(m, 7, big, 1024, reply, sizeof reply, &rlen), -EMSGSIZE);
    CHECK_EQ(execMasterTransact(m, 7, big, 1025, reply, sizeof reply, &rlen), -EMSGSIZE);
    CHECK_EQ(execMasterTransact(m, 7, big, 65535, reply, sizeof reply, &rlen), -EMSGSIZE);
    CHECK_EQ(execMasterBroadcast(m, big, 256), -EMSGSIZE);
    CHECK_EQ(execMasterBroadcast(m, NULL, 1), -EINVAL);
    CHECK_EQ(execMasterNextSeq(m, 0), -EINVAL);
    /* huge timeout and retries: the reply still ends the wait at once */
    CHECK_EQ(execMasterSetTimeout(m, UINT_MAX, UINT_MAX), 0);
    CHECK_EQ(execMasterTransact(m, 7, big, 255, reply, sizeof reply, &rlen), 0);
    CHECK_EQ(rlen, 255);
    /* reply larger than the caller's buffer: -ENOBUFS, length reported */
    CHECK_EQ(execMasterTransact(m, 7, big, 10, reply, 4, &rlen), -ENOBUFS);
    CHECK_EQ(rlen, 10);
    CHECK_EQ(execMasterTransact(m, 7, big, 0, NULL, 0, NULL), 0);
    CHECK_EQ(execMasterSetTimeout(m, 1000, 0), 0);
    CHECK_EQ(execMasterTransact(m, 8, big, 1, reply, sizeof reply, &rlen), -ETIMEDOUT);
    execSlaveStop(s);
    pthread_join(t, NULL);
    CHECK_EQ(execSlaveServe(s, INT_MAX), -ECANCELED);   /* after Stop: never waits */
    execSlaveClose(s);
    execMasterClose(m);
    fap_vbus_close(b);
}

/* ---- mikroc_rs485.h ---- */
static void test_mikroc(void)
{
    uint8_t out[MIKROC_RS485_FRAME_MAX];
    uint8_t d[4] = {0x96, 0xA9, 0x10, 0};
    CHECK_EQ(mikrocRS485_Encode(out, d, 4, 1, 1), -EINVAL);
    CHECK_EQ(mikrocRS485_Encode(out, d, UINT_MAX, 1, 1), -EINVAL);
    CHECK_EQ(mikrocRS485_Encode(out, NULL, 1, 1, 1), -EINVAL);
    CHECK_EQ(mikrocRS485_Encode(out, NULL, 0, 255, 0), MIKROC_RS485_FRAME_MIN);
    CHECK_EQ(mikrocRS485_Encode(out, d, 3, 0x96, 1), MIKROC_RS485_FRAME_MAX);
    CHECK(mikrocRS485_strerror(INT_MIN) != NULL);
    CHECK(mikrocRS485_strerror(INT_MAX) != NULL);
    mikrocRS485_ctx c;
    memset(&c, 0, sizeof c);
    char buf[MIKROC_RS485_MASTER_BUFFER] = {0};
    /* before Init */
    CHECK_EQ(mikrocRS485_CtxSend(&c, buf, 1, 1), -EPERM);
    CHECK_EQ(mikrocRS485_CtxPoll(&c, buf, 0), -EPERM);
    mikrocRS485_CtxInitMaster(&c);
    /* no port bound */
    CHECK_EQ(mikrocRS485_CtxSend(&c, buf, 1, 1), -ENOTCONN);
    CHECK_EQ(mikrocRS485_CtxPoll(&c, buf, INT_MAX), -ENOTCONN);   /* no hang */
    mikrocRS485_CtxReceive(&c, buf);
    CHECK_EQ(mikrocRS485_CtxResetRx(&c), 0);
    CHECK(mikrocRS485_CtxOpen(&c, NULL, 9600, NULL) < 0);
    CHECK(mikrocRS485_CtxOpen(&c, "/nonexistent", 9600, NULL) < 0);
    fap_vbus *b = open_bus(2);
    REQUIRE(b);
    fap_port_options po;
    quick_port(&po);
    CHECK(mikrocRS485_CtxOpen(&c, fap_vbus_port_path(b, 0), 12345, &po) < 0);
    REQUIRE(mikrocRS485_CtxOpen(&c, fap_vbus_port_path(b, 0), 0, &po) == 0);
    CHECK_EQ(mikrocRS485_CtxOpen(&c, fap_vbus_port_path(b, 0), 0, &po), -EBUSY);
    CHECK_EQ(mikrocRS485_CtxSend(&c, buf, 4, 1), -EINVAL);
    CHECK_EQ(mikrocRS485_CtxSend(&c, buf, UINT_MAX, 1), -EINVAL);
    CHECK_EQ(mikrocRS485_CtxSend(&c, NULL, 1, 1), -EINVAL);
    CHECK_EQ(mikrocRS485_CtxSend(&c, buf, 3, 255), 0);
    CHECK_EQ(mikrocRS485_CtxPoll(&c, buf, 0), 0);
    CHECK_EQ(mikrocRS485_CtxPoll(&c, buf, 1), 0);
    mikrocRS485_CtxGetStats(&c, NULL);
    /* slave at 1 hears the master's frame with a huge timeout */
    mikrocRS485_ctx sl;
    mikrocRS485_CtxInitSlave(&sl, 1);
    fap_port *sp = NULL;
    REQUIRE(fap_port_open(&sp, fap_vbus_port_path(b, 1), &po) == 0);
    CHECK_EQ(mikrocRS485_CtxBind(&sl, sp), 0);
    char sbuf[MIKROC_RS485_SLAVE_BUFFER] = {0};
    CHECK_EQ(mikrocRS485_CtxSend(&c, "abc", 3, 1), 0);
    CHECK_EQ(mikrocRS485_CtxPoll(&sl, sbuf, INT_MAX), MIKROC_RS485_POLL_READY);
    CHECK_EQ(mikrocRS485_CtxPoll(&sl, sbuf, INT_MAX), MIKROC_RS485_POLL_READY); /* already set */
    CHECK_EQ(mikrocRS485_CtxBind(&sl, NULL), 0);
    CHECK_EQ(mikrocRS485_CtxSend(&sl, "x", 1, 0), -ENOTCONN);
    fap_port_close(sp);
    /* after close */
    mikrocRS485_CtxClose(&c);
    mikrocRS485_CtxClose(&c);
    CHECK_EQ(mikrocRS485_CtxSend(&c, buf, 1, 1), -ENOTCONN);
    CHECK_EQ(mikrocRS485_CtxPoll(&c, buf, INT_MAX), -ENOTCONN);
    /* the vendor routines on the global contexts */
    RS485Master_Send(buf, 1, 1);                     /* before Init */
    CHECK_EQ(mikrocRS485_LastSendError(1), -EPERM);
    RS485Master_Init();
    RS485Master_Send(buf, 4, 1);
    CHECK_EQ(mikrocRS485_LastSendError(1), -EINVAL);
    RS485Master_Send(buf, (char)-1, 1);
    CHECK_EQ(mikrocRS485_LastSendError(1), -EINVAL);
    RS485Master_Send(buf, 1, 1);
    CHECK_EQ(mikrocRS485_LastSendError(1), -ENOTCONN);
    RS485Master_Receive(buf);                        /* no port: nothing */
    CHECK_EQ(mikrocRS485_Poll(buf, 1, INT_MAX), -ENOTCONN);
    CHECK(mikrocRS485_Open(NULL, 9600, NULL) < 0);
    REQUIRE(mikrocRS485_Open(fap_vbus_port_path(b, 0), 0, &po) == 0);
    CHECK_EQ(mikrocRS485_Open(fap_vbus_port_path(b, 0), 0, &po), -EBUSY);
    RS485Slave_Init(0);
    RS485Slave_Send(buf, 3);
    CHECK_EQ(mikrocRS485_LastSendError(0), 0);
    RS485Slave_Send(buf, 100);
    CHECK_EQ(mikrocRS485_LastSendError(0), -EINVAL);
    for (int v = 0; v < 256; v++) {                  /* any byte, either node */
        mikrocRS485Master_ReceiveByte(buf, (unsigned char)v);
        mikrocRS485Slave_ReceiveByte(sbuf, (unsigned char)v);
    }
    mikrocRS485_stats ms;
    mikrocRS485_GetStats(1, &ms);
    mikrocRS485_GetStats(0, NULL);
    (void)mikrocRS485_LastRxError(1);
    mikrocRS485_Close();
    mikrocRS485_Close();
    RS485Slave_Send(buf, 1);
    CHECK_EQ(mikrocRS485_LastSendError(0), -ENOTCONN);
    CHECK_EQ(mikrocRS485_Bind(NULL), 0);
    fap_vbus_close(b);
}

UNIT_MAIN(UNIT(test_port), UNIT(test_vbus), UNIT(test_fapx), UNIT(test_classic),
          UNIT(test_exec_codec), UNIT(test_exec_engine), UNIT(test_mikroc))
