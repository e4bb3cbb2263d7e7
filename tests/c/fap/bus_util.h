/* Helpers for the tests that run real engines on the virtual bus. */
#ifndef FAP_BUS_UTIL_H
#define FAP_BUS_UTIL_H
#include "fapx.h"
#include "fap_vbus.h"
#include "unit.h"
#include <errno.h>
#include <stdio.h>

/* Fast protocol timing for tests: the rules are the same, only shorter. */
static inline void fast_options(fapx_options *o, unsigned mode, unsigned id)
{
    fapx_options_init(o);
    o->mode = mode;
    o->id = id;
    /* long enough that a loaded CI machine (sanitizers, 2 cores) does not
     * miss them by accident; exact timing is tested on the fake clock */
    o->idc_us = 300000;        /* 300 ms */
    o->id_answer_us = 50000;   /* 50 ms */
    o->data_done_us = 200000;  /* 200 ms */
    o->send_budget_us = 100000; /* 100 ms */
    o->reopen_us = 20000;
    o->port.rs485_mode = FAP_RS485_NONE;
}

/* Events read while waiting for another one are kept here, so that
 * waiting for A then B works whatever order they came in. */
static struct { fapx *h; fapx_event ev; } ev_backlog[512];
static int ev_backlog_n;

static inline int backlog_take(fapx *h, int type, unsigned id, fapx_event *out)
{
    for (int i = 0; i < ev_backlog_n; i++) {
        if (ev_backlog[i].h == h && ev_backlog[i].ev.type == type && ev_backlog[i].ev.id == id) {
            if (out)
                *out = ev_backlog[i].ev;
            ev_backlog[i] = ev_backlog[--ev_backlog_n];
            return 1;
        }
    }
    return 0;
}

/* Forget the backlog of a handle about to be closed. */
static inline void backlog_forget(fapx *h)
{
    for (int i = 0; i < ev_backlog_n;)
        if (ev_backlog[i].h == h)
            ev_backlog[i] = ev_backlog[--ev_backlog_n];
        else
            i++;
}

/* Wait for event (type, id) (also one seen earlier); 0 or -ETIMEDOUT. */
static inline int wait_event(fapx *h, int type, unsigned id, int timeout_ms, fapx_event *out)
{
    if (backlog_take(h, type, id, out))
        return 0;
    int64_t end = fap_port_now_ns() + (int64_t)timeout_ms * 1000000;
    for (;;) {
        int64_t left = (end - fap_port_now_ns()) / 1000000;
        if (left < 0)
            return -ETIMEDOUT;
        fapx_event ev;
        int rc = fapx_event_wait(h, &ev, (int)left);
        if (rc < 0)
            return rc;
        if (ev.type == type && ev.id == id) {
            if (out)
                *out = ev;
            return 0;
        }
        if (ev_backlog_n < (int)(sizeof ev_backlog / sizeof ev_backlog[0])) {
            ev_backlog[ev_backlog_n].h = h;
            ev_backlog[ev_backlog_n].ev = ev;
            ev_backlog_n++;
        }
    }
}

static inline fap_vbus *open_bus(unsigned ports, unsigned baud)
{
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    bo.n_ports = ports;
    bo.baud = baud;
    fap_vbus *bus = NULL;
    int rc = fap_vbus_open(&bus, &bo);
    if (rc < 0) {
        fprintf(stderr, "fap_vbus_open: %d\n", rc);
        return NULL;
    }
    return bus;
}
#endif
