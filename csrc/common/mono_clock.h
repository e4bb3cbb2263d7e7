/* Monotonic time in nanoseconds. Engines take "now" as an argument so the
 * sans-I/O state machines can be driven by a fake clock in tests; only the
 * I/O layer calls lf_now_ns(). */
#ifndef LF_MONO_CLOCK_H
#define LF_MONO_CLOCK_H
#include <stdint.h>
#include <time.h>

typedef int64_t lf_ns;                 /* CLOCK_MONOTONIC nanoseconds */
#define LF_NS_PER_MS  1000000LL
#define LF_NS_PER_US  1000LL
#define LF_NS_PER_S   1000000000LL
#define LF_NEVER      INT64_MAX        /* a deadline that never comes */

lf_ns lf_now_ns(void);
struct timespec lf_ns_to_timespec(lf_ns t);
/* Milliseconds from now until deadline for poll(): 0 if past, -1 if never,
 * rounded up so poll never wakes before the deadline. */
int lf_poll_timeout_ms(lf_ns deadline, lf_ns now);
/* Sleep until an absolute CLOCK_MONOTONIC deadline (restarts on EINTR). */
void lf_sleep_until(lf_ns deadline);
/* Time one byte takes on the wire: 10 bits (start, 8 data, stop). */
static inline lf_ns lf_char_time_ns(unsigned baud)
{
    return baud ? (lf_ns)(10LL * LF_NS_PER_S / baud) : 0;
}
#endif
