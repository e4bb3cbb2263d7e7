/* classic_noclose.c - a vendor-API program that ends without a close (the
 * vendor API has none): configures a FAP master on the port, prints the
 * kernel RS-485 config it put in force, returns from main. At exit the
 * library must give the port its original configuration back. */
#include <fcntl.h>
#include <linux/serial.h>
#include <stdio.h>
#include <string.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <fap.h>

int main(int argc, char **argv)
{
    char *dev = argc > 1 ? argv[1] : "/dev/ttyAMA0";
    if (fapInit(dev, 115200) != GOOD)
        return BAD;
    fapT config = {.mode = FAP_MASTER, .id = 0, .idcTime = 15};
    if (fapConfig(&config) != GOOD || fapAddSlave(7) != GOOD)
        return BAD;
    /* the kernel's view through the library's own descriptor */
    for (int fd = 3; fd < 256; fd++) {
        char link[64], target[64];
        snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
        ssize_t n = readlink(link, target, sizeof target - 1);
        struct serial_rs485 r;
        memset(&r, 0, sizeof r);
        if (n > 0 && (target[n] = 0, strcmp(target, dev) == 0) && ioctl(fd, TIOCGRS485, &r) == 0) {
            printf("classic_noclose: while open flags=0x%x before=%u after=%u\n", r.flags,
                   r.delay_rts_before_send, r.delay_rts_after_send);
            break;
        }
    }
    fflush(stdout);
    return GOOD;   /* no close: the vendor API has none */
}
