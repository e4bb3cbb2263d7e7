/* fd_util.h - small fd helpers shared by the layers' teardown code. */
#ifndef LF_FD_UTIL_H
#define LF_FD_UTIL_H

#include <stddef.h>
#include <unistd.h>

/* Close each of the n fds that is open (-1: never opened). */
static inline void lf_close_fds(const int *fds, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (fds[i] >= 0)
            close(fds[i]);
}

#endif
