/* The vendor's classic API (fap.h) over one default fapx handle.
 *
 * fapInit opens the port (the handle exists, no engine yet); fapConfig
 * starts the engine as master or slave (a second fapConfig stops it and
 * starts it again with the new configuration, keeping queued data).
 * Between fapInit and fapConfig: fapTx queues (sent once configured),
 * fapRx reports E_RES, fapAddSlave/fapRemSlave edit the list a master will
 * use (fapConfig as a slave discards it). All calls are thread-safe.
 * The vendor API has no close: at normal process exit (atexit) the port is
 * closed, which gives it back its original RS-485 configuration. */
#include "fap.h"
#include "fapx.h"
#include "fap/fapx_internal.h"
#include <errno.h>
#include <pthread.h>
#include <stdlib.h>
#include <unistd.h>
#include <string.h>

static pthread_rwlock_t g_lock = PTHREAD_RWLOCK_INITIALIZER;
static fapx *g_h;                 /* set by fapInit */
static int g_configured;
static int g_have_opts;
static fapx_options g_opts;

void fapClassicSetOptions(const fapx_options *o)
{
    pthread_rwlock_wrlock(&g_lock);
    g_have_opts = o != NULL;
    if (o)
        g_opts = *o;
    pthread_rwlock_unlock(&g_lock);
}

fapx *fapClassicHandle(void)
{
    pthread_rwlock_rdlock(&g_lock);
    fapx *h = g_configured ? g_h : NULL;
    pthread_rwlock_unlock(&g_lock);
    return h;
}

void fapClassicClose(void)
{
    pthread_rwlock_wrlock(&g_lock);
    fapx *h = g_h;
    g_h = NULL;
    g_configured = 0;
    pthread_rwlock_unlock(&g_lock);
    lf_fapx_destroy(h);
}

static pthread_once_t g_atexit_once = PTHREAD_ONCE_INIT;
static pid_t g_owner_pid;

static void classic_at_exit(void)
{
    /* A forked child that calls exit() has no engine threads and must not
     * take the parent's port configuration away. */
    if (getpid() == g_owner_pid)
        fapClassicClose();
}

static void classic_register_atexit(void)
{
    g_owner_pid = getpid();
    (void)atexit(classic_at_exit);   /* a full atexit table: nothing restored at exit */
}

static int classic_baud(usys b)
{
    return b == 9600 || b == 19200 || b == 38400 || b == 57600 || b == 115200;
}

usys fapInit(char *devName, usys baudRate)
{
    pthread_rwlock_wrlock(&g_lock);
    usys rc = GOOD;
    if (g_h) {
        rc = E_INIT;
    } else if (!devName || !classic_baud(baudRate)) {
        rc = BAD;
    } else {
        fapx_options o;
        if (g_have_opts)
            o = g_opts;
        else
            fapx_options_init(&o);
        o.port.baud = baudRate;
        /* the real-time option of the classic API: FAP_REALTIME (docs/realtime.md);
         * a bad spec, or one the process may not have, fails fapInit */
        char *rt = getenv("FAP_REALTIME");
        if (rt && *rt && fap_port_rt_from_env(&o.port.rt, NULL, 0) < 0) {
            rc = BAD;
        } else if (lf_fapx_create(&g_h, devName, &o) < 0) {
            g_h = NULL;
            rc = BAD;
        } else {
            pthread_once(&g_atexit_once, classic_register_atexit);
        }
    }
    pthread_rwlock_unlock(&g_lock);
    return rc;
}

usys fapConfig(fapT *config)
{
    pthread_rwlock_wrlock(&g_lock);
    usys rc = GOOD;
    if (!g_h)
        rc = E_INIT;
    else if (!config || (config->mode != FAP_MASTER && config->mode != FAP_SLAVE))
        rc = E_PARAM;
    else if (config->mode == FAP_MASTER ? config->id != 0
                                        : (config->id == 0 || config->id > FAPX_MAX_ID))
        rc = E_VALUE;
    if (rc == GOOD) {
        /* Timing from fapClassicSetOptions (as it is now), vendor defaults
         * for zero fields; idcTime in seconds wins when not 0. The handle
         * is stopped first, so its options can be changed here. */
        lf_fapx_stop(g_h);
        fapx_options t;
        if (g_have_opts)
            t = g_opts;
        else
            fapx_options_init(&t);
        lf_fapx_fill_defaults(&t);
        g_h->o.idc_us = t.idc_us;
        g_h->o.id_answer_us = t.id_answer_us;
        g_h->o.data_done_us = t.data_done_us;
        g_h->o.send_budget_us = t.send_budget_us;
        g_h->o.gap_us = t.gap_us;
        g_h->o.reopen_us = t.reopen_us;
        if (config->mode == FAP_MASTER && config->idcTime)
            g_h->o.idc_us = (uint64_t)config->idcTime * 1000000u;
        if (lf_fapx_start(g_h, config->mode, config->id) < 0)
            rc = BAD;
        else
            g_configured = 1;
    }
    pthread_rwlock_unlock(&g_lock);
    return rc;
}

static usys list_call(usys id, int add)
{
    pthread_rwlock_rdlock(&g_lock);
    usys rc;
    if (!g_h) {
        rc = E_INIT;
    } else {
        int r = add ? fapx_add_slave(g_h, id) : fapx_remove_slave(g_h, id);
        rc = r == 0 ? GOOD : r == -EPERM ? E_PARAM : r == -ESHUTDOWN ? E_INIT : E_VALUE;
    }
    pthread_rwlock_unlock(&g_lock);
    return rc;
}

usys fapAddSlave(usys id)
{
    return list_call(id, 1);
}

usys fapRemSlave(usys id)
{
    return list_call(id, 0);
}

usys fapTx(u8 *data, usys size, usys id)
{
    pthread_rwlock_rdlock(&g_lock);
    usys rc;
    if (!g_h) {
        rc = E_INIT;
    } else if (!data || size == 0 || size > MAX_DATA_SIZE || id > FAPX_MAX_ID) {
        rc = E_VALUE;
    } else {
        int r = fapx_tx(g_h, id, data, size);
        rc = r == 0 ? GOOD : r == -EAGAIN ? E_RES : r == -ESHUTDOWN ? E_INIT : E_VALUE;
    }
    pthread_rwlock_unlock(&g_lock);
    return rc;
}

usys fapRx(u8 *data, usys *size, usys *id)
{
    pthread_rwlock_rdlock(&g_lock);
    usys rc;
    if (!g_h) {
        rc = E_INIT;
    } else if (!data || !size || !id) {
        rc = E_PARAM;
    } else {
        unsigned src = 0;
        int n = fapx_rx(g_h, data, MAX_DATA_SIZE, &src);
        if (n >= 0) {
            *size = (usys)n;
            *id = src;
            rc = GOOD;
        } else {
            rc = E_RES;
        }
    }
    pthread_rwlock_unlock(&g_lock);
    return rc;
}
