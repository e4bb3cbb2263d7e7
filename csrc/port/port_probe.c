/* port_probe.c - read a device's current line and RS-485 configuration
 * without changing it (for `fap ports` and similar listings). */
#include "port/port_internal.h"

#include <fcntl.h>
#include <string.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <unistd.h>

int fap_port_probe(const char *path, unsigned *baud, uint32_t *rs485_flags,
                   uint32_t *delay_before_ms, uint32_t *delay_after_ms)
{
    if (!path)
        return -EINVAL;
    int fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return -errno;
    int err = 0;
    struct termios t;
    if (tcgetattr(fd, &t) < 0) {
        err = -errno;
        goto out;
    }
    if (baud)
        *baud = lf_port_speed_to_baud(cfgetospeed(&t));
    struct serial_rs485 r;
    memset(&r, 0, sizeof r);
    if (ioctl(fd, TIOCGRS485, &r) < 0) {
        err = -errno;
        goto out;
    }
    if (rs485_flags)
        *rs485_flags = r.flags;
    if (delay_before_ms)
        *delay_before_ms = r.delay_rts_before_send;
    if (delay_after_ms)
        *delay_after_ms = r.delay_rts_after_send;
    /* Can the driver switch it? Writing back exactly what it reported changes
     * nothing; a plain 16550 (8250) answers TIOCGRS485 but refuses this. */
    if (ioctl(fd, TIOCSRS485, &r) < 0)
        err = errno == ENOTTY || errno == EINVAL || errno == EOPNOTSUPP ? 1 : -errno;
out:
    close(fd);
    return err;
}
