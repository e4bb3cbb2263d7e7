/* port_cancel.c - a port whose waits a stop can end (port_cancel.h). Any
 * transport (device, tcp://, rfc2217://): the cancel fd is the port's own,
 * polled beside the line in every wait (port_io.c, poll_until). */
#include "port/port_cancel.h"

#include <errno.h>
#include <stdint.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "port/port_internal.h"

int lf_port_open_cancellable(fap_port **out, const char *path, const fap_port_options *o,
                             const int *cancel_fd)
{
    if (!cancel_fd || !out)
        return -EINVAL;
    /* watched from the start: a network open's name lookup, connect and
     * negotiation end with -ECANCELED too */
    return lf_port_open_cancel(out, path, o, cancel_fd);
}

int fap_port_open_cancellable(fap_port **out, const char *path, const fap_port_options *o,
                              const int *cancel_fd)
{
    return lf_port_open_cancellable(out, path, o, cancel_fd);
}

int lf_port_open_interruptible(fap_port **out, const char *path, const fap_port_options *o)
{
    if (!out)
        return -EINVAL;
    int fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (fd < 0)
        return -errno;
    int err = fap_port_open(out, path, o);
    if (err) {
        close(fd);
        return err;
    }
    (*out)->intr_fd = fd;               /* closed by fap_port_close */
    (*out)->cancel_fd = &(*out)->intr_fd;
    return 0;
}

void lf_port_interrupt(fap_port *p)
{
    if (!p)
        return;
    __atomic_store_n(&p->interrupted, 1, __ATOMIC_RELEASE);
    if (p->intr_fd >= 0) {
        uint64_t one = 1;
        ssize_t w = write(p->intr_fd, &one, sizeof one);
        (void)w;   /* EAGAIN: already signalled */
    }
}

int lf_port_interrupted(const fap_port *p)
{
    return p && __atomic_load_n(&p->interrupted, __ATOMIC_ACQUIRE);
}
