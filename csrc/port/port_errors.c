/* port_errors.c - names for modes and error codes, and which codes mean
 * the device is gone. */
#include <errno.h>
#include <string.h>

#include "fap_port.h"
#include "port/port_internal.h"

const char *fap_rs485_mode_name(fap_rs485_mode m)
{
    switch (m) {
    case FAP_RS485_AUTO: return "auto";
    case FAP_RS485_KERNEL: return "kernel";
    case FAP_RS485_SOFT_RTS: return "soft-rts";
    case FAP_RS485_NONE: return "none";
    case FAP_RS485_GPIO: return "gpio";
    }
    return "unknown";
}

const char *fap_port_strerror(int err)
{
    switch (err) {
    case 0: return "success";
    case FAP_PORT_ECOLLISION: return "bus collision: the echo differs from the bytes sent";
    case FAP_PORT_ECLOSED: return "port closed";
    case FAP_PORT_EURL: return "bad port URL (tcp://HOST:PORT or rfc2217://HOST:PORT)";
    case FAP_PORT_ENET485: return "RS-485 direction on a network port is the server's: "
                                  "use mode none (or auto)";
    case FAP_PORT_ERESOLVE: return "host name not resolved (unknown, or no DNS answer within "
                                   "connect_ms)";
    case FAP_PORT_EREFUSED: return "the RFC 2217 server refused a line setting";
    default: break;
    }
    const char *rt = lf_port_rt_strerror(err);   /* port_rt.c */
    if (rt)
        return rt;
    long e = err < 0 ? -(long)err : err;   /* -INT_MIN does not fit an int */
    /* strerrordesc_np: thread-safe, no locale, NULL for unknown numbers. */
    const char *s = (e > 0 && e < 4096) ? strerrordesc_np(e) : NULL;
    return s ? s : "unknown error";
}

int fap_port_error_is_gone(int err)
{
    switch (err) {
    case -EIO:      /* tty hung up (pty master closed), USB read error */
    case -ENXIO:    /* USB adapter unplugged */
    case -ENODEV:   /* unplugged; between a reopen's close and open */
    case -EPIPE:    /* the far end of the stream closed */
    case -EBADF:    /* the fd was closed under the call */
    case FAP_PORT_ECLOSED:
        return 1;
    default:
        return 0;
    }
}
