/* port_baud.c - the baud rates the port layer accepts and their termios
 * speeds (sans-I/O). Its own file so the code that reads a struct termios
 * (port_device.c, port_probe.c) and the option check (port.c) share it
 * without calling into each other. */
#include <errno.h>
#include <stddef.h>
#include <termios.h>

#include "fap_port.h"
#include "port/port_device.h"

static const struct {
    unsigned baud;
    speed_t speed;
} baud_table[] = {
    {50, B50}, {75, B75}, {110, B110}, {134, B134}, {150, B150},
    {200, B200}, {300, B300}, {600, B600}, {1200, B1200}, {1800, B1800},
    {2400, B2400}, {4800, B4800}, {9600, B9600}, {19200, B19200},
    {38400, B38400}, {57600, B57600}, {115200, B115200},
    {230400, B230400}, {460800, B460800}, {500000, B500000},
    {576000, B576000}, {921600, B921600}, {1000000, B1000000},
    {1152000, B1152000}, {1500000, B1500000}, {2000000, B2000000},
    {2500000, B2500000}, {3000000, B3000000}, {3500000, B3500000},
    {4000000, B4000000},
};

int lf_port_baud_to_speed(unsigned baud, speed_t *out)
{
    for (size_t i = 0; i < sizeof baud_table / sizeof baud_table[0]; i++) {
        if (baud_table[i].baud == baud) {
            *out = baud_table[i].speed;
            return 0;
        }
    }
    return -EINVAL;
}

int lf_port_baud_ok(unsigned baud)
{
    speed_t speed;
    return lf_port_baud_to_speed(baud, &speed) == 0;
}

unsigned lf_port_speed_to_baud(speed_t speed)
{
    for (size_t i = 0; i < sizeof baud_table / sizeof baud_table[0]; i++)
        if (baud_table[i].speed == speed)
            return baud_table[i].baud;
    return 0;
}

unsigned fap_port_baud_rate(size_t i)
{
    return i < sizeof baud_table / sizeof baud_table[0] ? baud_table[i].baud : 0;
}
