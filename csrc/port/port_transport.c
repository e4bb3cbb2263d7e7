/* port_transport.c - the one place that maps a port string to its
 * transport (port_backend.h): fap_port_kind says what a string is (one
 * parse, port_url.c), and the open hands a device path to the device
 * transport (port_device.c, over the real OS table) and a URL to the
 * network transport (port_net.c), then opens the port (port.c) over the
 * transport chosen. Neither side calls the other: only this file calls
 * both, so a new transport (a daemon's socket, TLS) is one file and one row
 * here. */
#include <errno.h>
#include <stddef.h>

#include "fap_port.h"
#include "port/port_backend.h"
#include "port/port_device.h"
#include "port/port_net.h"
#include "port/port_url.h"

int fap_port_kind(const char *path)
{
    if (!path)
        return FAP_PORT_KIND_INVALID;
    lf_port_url u;
    int err = lf_port_url_parse(path, &u);
    switch (u.scheme) {
    case LF_PORT_DEVICE: return FAP_PORT_KIND_DEVICE;
    case LF_PORT_OTHER: return FAP_PORT_KIND_OTHER;
    case LF_PORT_TCP: return err ? FAP_PORT_KIND_INVALID : FAP_PORT_KIND_TCP;
    case LF_PORT_RFC2217: return err ? FAP_PORT_KIND_INVALID : FAP_PORT_KIND_RFC2217;
    }
    return FAP_PORT_KIND_INVALID;
}

int lf_port_open_cancel(fap_port **out, const char *path, const fap_port_options *o,
                        const int *cancel_fd)
{
    if (!out || !path)
        return -EINVAL;
    lf_port_url u;
    int err = lf_port_url_parse(path, &u);
    const lf_port_transport *tr;
    void *ctx;
    if (u.scheme == LF_PORT_DEVICE) {
        err = lf_port_device_new(&lf_port_posix_os, NULL, &tr, &ctx);
        if (err)
            return err;
        return lf_port_open_transport(out, path, o, tr, ctx, cancel_fd);
    }
    if (err)
        return err;   /* FAP_PORT_EURL: a scheme we do not open, or a URL that does not parse */
    err = lf_port_net_prepare(&u, o, &tr, &ctx);
    if (err)
        return err;
    return lf_port_open_transport(out, path, o, tr, ctx, cancel_fd);
}

int lf_port_open_with_backend(fap_port **out, const char *path, const fap_port_options *o,
                              const lf_port_os *os, void *ctx)
{
    const lf_port_transport *tr;
    void *dev;
    int err = lf_port_device_new(os, ctx, &tr, &dev);
    if (err)
        return err;
    return lf_port_open_transport(out, path, o, tr, dev, NULL);
}

int fap_port_open(fap_port **out, const char *path, const fap_port_options *o)
{
    return lf_port_open_cancel(out, path, o, NULL);
}
