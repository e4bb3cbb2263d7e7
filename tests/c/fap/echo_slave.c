/* Test helper process: a FAP slave written against the CLASSIC API that
 * echoes every DATA it receives back to its sender as "echo:<data>".
 *   echo_slave DEVICE ID IDC_US ID_ANSWER_US DATA_DONE_US BUDGET_US
 * Prints "ready" on stdout once configured; exits when stdin closes (the
 * test's end of the pipe) or on SIGTERM/SIGKILL. Waits on the classic
 * handle's notify fd, never sleeps. */
#include "fap.h"
#include "fapx.h"
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

int main(int argc, char **argv)
{
    if (argc < 7) {
        fprintf(stderr, "usage: %s DEVICE ID IDC_US ID_ANSWER_US DATA_DONE_US BUDGET_US\n", argv[0]);
        return 2;
    }
    fapx_options o;
    fapx_options_init(&o);
    o.idc_us = strtoull(argv[3], NULL, 0);
    o.id_answer_us = strtoull(argv[4], NULL, 0);
    o.data_done_us = strtoull(argv[5], NULL, 0);
    o.send_budget_us = strtoull(argv[6], NULL, 0);
    o.port.rs485_mode = FAP_RS485_NONE;
    fapClassicSetOptions(&o);
    if (fapInit(argv[1], 115200) != GOOD)
        return 3;
    fapT cfg = { .id = (usys)atoi(argv[2]), .mode = FAP_SLAVE, .idcTime = 0 };
    if (fapConfig(&cfg) != GOOD)
        return 4;
    printf("ready\n");
    fflush(stdout);
    struct pollfd pf[2] = {
        { .fd = fapx_notify_fd(fapClassicHandle()), .events = POLLIN },
        { .fd = STDIN_FILENO, .events = POLLIN },
    };
    for (;;) {
        u8 data[MAX_DATA_SIZE], reply[MAX_DATA_SIZE];
        usys size, src;
        while (fapRx(data, &size, &src) == GOOD) {
            usys n = size + 5 > MAX_DATA_SIZE ? MAX_DATA_SIZE : size + 5;
            memcpy(reply, "echo:", 5);
            memcpy(reply + 5, data, n - 5);
            while (fapTx(reply, n, src) == E_RES) {
                /* tx queue full: wait for the engine to send some */
                fapx_flush(fapClassicHandle(), 1000);
            }
        }
        fapx_event ev;
        while (fapx_event_get(fapClassicHandle(), &ev) == 0)
            ;
        if (poll(pf, 2, -1) < 0)
            break;
        if (pf[1].revents)
            break;                         /* the test closed our stdin */
    }
    fapClassicClose();
    return 0;
}
