/* Wake-up counting for the tests that check how often an engine's thread
 * sleeps per exchange on a paced virtual bus (counts, never durations). */
#ifndef LF_TEST_WAKEUPS_H
#define LF_TEST_WAKEUPS_H

#include <sys/resource.h>

#include "fap_vbus.h"

/* Voluntary context switches of the calling thread so far (-1: unknown). */
static inline long test_thread_wakeups(void)
{
    struct rusage ru;
    return getrusage(RUSAGE_THREAD, &ru) == 0 ? ru.ru_nvcsw : -1;
}

/* A 2-port bus paced at baud (each byte delivered at the end of its wire
 * time), or NULL. */
static inline fap_vbus *test_paced_bus(unsigned baud)
{
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    bo.n_ports = 2;
    bo.baud = baud;
    fap_vbus *bus = NULL;
    return fap_vbus_open(&bus, &bo) == 0 ? bus : NULL;
}

#endif
