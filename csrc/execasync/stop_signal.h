/* stop_signal.h - execMasterStop: one flag, one eventfd (the slave stops
 * through its port's interrupt flag and its own eventfd, engine_slave.c). */
#ifndef LF_EXEC_STOP_SIGNAL_H
#define LF_EXEC_STOP_SIGNAL_H

#include <stdint.h>
#include <unistd.h>

/* Set *stopped and make stop_fd readable: async-signal-safe (an atomic
 * store and one write). */
static inline void lf_exec_signal_stop(int *stopped, int stop_fd)
{
    __atomic_store_n(stopped, 1, __ATOMIC_RELEASE);
    uint64_t one = 1;
    ssize_t w = write(stop_fd, &one, sizeof one);
    (void)w;   /* EAGAIN: already signalled */
}

#endif
