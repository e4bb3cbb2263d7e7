/* vbus_node.c - a separate C program run on a bus port by test_vbus:
 *     vbus_node PATH HEX_FRAME REPLY_LEN
 * opens PATH, sends the frame, waits (up to 5 s) for REPLY_LEN bytes and
 * prints them as hex on stdout. Exit 0 on success, 2 on usage, 1 on failure. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vbus_test_io.h"

int main(int argc, char **argv)
{
    if (argc != 4)
        return 2;
    uint8_t frame[256], reply[256];
    size_t n = 0;
    for (const char *h = argv[2]; h[0] && h[1] && n < sizeof frame; h += 2) {
        unsigned v;
        if (sscanf(h, "%2x", &v) != 1)
            return 2;
        frame[n++] = (uint8_t)v;
    }
    size_t want = (size_t)strtoul(argv[3], NULL, 10);
    if (want > sizeof reply)
        return 2;
    int fd = vt_open(argv[1]);
    if (fd < 0) {
        fprintf(stderr, "vbus_node: open %s: %s\n", argv[1], strerror(-fd));
        return 1;
    }
    if (vt_write_all(fd, frame, n) != 0)
        return 1;
    ssize_t got = vt_read_n(fd, reply, want, 5000);
    close(fd);
    if (got != (ssize_t)want)
        return 1;
    for (size_t i = 0; i < want; i++)
        printf("%02x", reply[i]);
    printf("\n");
    return 0;
}
