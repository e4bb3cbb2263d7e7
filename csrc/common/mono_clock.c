#include "common/mono_clock.h"
#include <errno.h>

lf_ns lf_now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (lf_ns)ts.tv_sec * LF_NS_PER_S + ts.tv_nsec;
}

struct timespec lf_ns_to_timespec(lf_ns t)
{
    struct timespec ts = { .tv_sec = t / LF_NS_PER_S, .tv_nsec = t % LF_NS_PER_S };
    return ts;
}

int lf_poll_timeout_ms(lf_ns deadline, lf_ns now)
{
    if (deadline == LF_NEVER)
        return -1;
    if (deadline <= now)
        return 0;
    lf_ns ms = (deadline - now + LF_NS_PER_MS - 1) / LF_NS_PER_MS;
    return ms > 0x7fffffff ? 0x7fffffff : (int)ms;
}

void lf_sleep_until(lf_ns deadline)
{
    struct timespec ts = lf_ns_to_timespec(deadline);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR)
        ;
}
