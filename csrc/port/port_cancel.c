/* port_cancel.c - a port whose waits a stop can end (port_cancel.h). Any
 * transport (device, tcp://, rfc2217://): the cancel fd is the port's own,
 * polled beside the line in every wait (port_io.c, poll_until). */
#include "port/port_cancel.h"

#include <errno.h>

#include "port/port_internal.h"

int lf_port_open_cancellable(fap_port **out, const char *path, const fap_port_options *o,
                             const int *cancel_fd)
{
    if (!cancel_fd || !out)
        return -EINVAL;
    int err = fap_port_open(out, path, o);
    if (!err)
        (*out)->cancel_fd = cancel_fd;
    return err;
}

int fap_port_open_cancellable(fap_port **out, const char *path, const fap_port_options *o,
                              const int *cancel_fd)
{
    return lf_port_open_cancellable(out, path, o, cancel_fd);
}
