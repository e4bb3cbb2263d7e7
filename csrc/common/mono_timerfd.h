/* A timerfd armed at an absolute CLOCK_MONOTONIC deadline (lf_ns), for the
 * threads that wait in poll/epoll (the FAP engine, the vbus relay). */
#ifndef LF_MONO_TIMERFD_H
#define LF_MONO_TIMERFD_H
#include <sys/timerfd.h>
#include "common/mono_clock.h"

/* Arm tfd (created on CLOCK_MONOTONIC) to expire at deadline; LF_NEVER
 * disarms it. A deadline <= 0 expires at once (0 itself would disarm). */
static inline void lf_timerfd_arm_at(int tfd, lf_ns deadline)
{
    struct itimerspec its = {{0, 0}, {0, 0}};
    if (deadline != LF_NEVER)
        its.it_value = lf_ns_to_timespec(deadline > 0 ? deadline : 1);
    timerfd_settime(tfd, TFD_TIMER_ABSTIME, &its, NULL);
}
#endif
