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
    o->idc_us = 150000;        /* 150 ms */
    o->id_answer_us = 20000;   /* 20 ms */
    o->data_done_us = 60000;   /* 60 ms */
    o->send_budget_us = 40000; /* 40 ms */
    o->reopen_us = 20000;
    o->port.rs485_mode = FAP_RS485_NONE;
}

/* Wait for event (type, id), skipping others; 0 or -ETIMEDOUT. */
static inline int wait_event(fapx *h, int type, unsigned id, int timeout_ms, fapx_event *out)
{
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
