/* port_gpio.c - a GPIO line as the RS-485 driver-enable (DE/RE) pin, through
 * the Linux GPIO character device, uAPI v2 (GPIO_V2_GET_LINE_IOCTL and
 * GPIO_V2_LINE_SET_VALUES_IOCTL from linux/gpio.h). Debian 12's libgpiod
 * is 1.6 (the v1 API): the ioctls directly need no library at all.
 * These are the posix OS table's gpio_open / gpio_set; tests use a fake. */
#include "port/port_internal.h"
#include "port/port_device.h"

#include <fcntl.h>
#include <linux/gpio.h>
#include <string.h>
#include <sys/ioctl.h>
#include <unistd.h>

int lf_port_gpio_open(void *ctx, const char *chip, unsigned line, int value)
{
    (void)ctx;
    if (!chip || line >= 512)   /* gpiochip lines are offsets < ngpio (u32) */
        return -EINVAL;
    int cfd = open(chip, O_RDWR | O_CLOEXEC);
    if (cfd < 0)
        return -errno;
    struct gpio_v2_line_request req;
    memset(&req, 0, sizeof req);
    req.offsets[0] = line;
    req.num_lines = 1;
    strncpy(req.consumer, "libfap rs485 DE", sizeof req.consumer - 1);
    req.config.flags = GPIO_V2_LINE_FLAG_OUTPUT;
    /* the initial value in the same request: no glitch at the wrong level */
    req.config.num_attrs = 1;
    req.config.attrs[0].attr.id = GPIO_V2_LINE_ATTR_ID_OUTPUT_VALUES;
    req.config.attrs[0].attr.values = value ? 1 : 0;
    req.config.attrs[0].mask = 1;
    int err = ioctl(cfd, GPIO_V2_GET_LINE_IOCTL, &req) < 0 ? -errno : 0;
    close(cfd);   /* the line fd lives on its own */
    if (err)
        return err;
    int fl = fcntl(req.fd, F_GETFD);
    if (fl >= 0)
        (void)fcntl(req.fd, F_SETFD, fl | FD_CLOEXEC);
    return req.fd;
}

int lf_port_gpio_set(void *ctx, int line_fd, int value)
{
    (void)ctx;
    struct gpio_v2_line_values v = {.bits = value ? 1 : 0, .mask = 1};
    return ioctl(line_fd, GPIO_V2_LINE_SET_VALUES_IOCTL, &v) < 0 ? -errno : 0;
}
