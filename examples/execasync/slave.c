/* exec async slave: answers commands with a packed reading until
 * interrupted. Usage: exec_slave DEVICE NODE [TURNAROUND_US] */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <exec_async_engine.h>

#include "reading.h"

static execSlave *slave;

static void on_signal(int sig)
{
    (void)sig;
    execSlaveStop(slave);   /* async-signal-safe: one write to an eventfd */
}

static int handle(void *ctx, const execSlaveRequest *req, byte *reply, word cap)
{
    int32_t *total = ctx;
    struct command cmd;
    if (req->node == EXEC_ASYNC_BROADCAST || req->len != 3 || cap < 13)
        return -1;                           /* nothing to answer */
    execUnPackDataEx((byte *)&cmd, (byte *)req->data, command_desc);
    *total += cmd.channel;                   /* applied once per request, retries or not */
    struct reading r = {.channel = (byte)cmd.channel, .raw = 0x1234, .total = *total,
                        .delta = {-1, 0, 1}};
    return execPackDataEx(reply, (byte *)&r, reading_desc);
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: %s DEVICE NODE [TURNAROUND_US]\n", argv[0]);
        return 2;
    }
    fap_port_options po;
    fap_port_options_init(&po);
    po.turnaround_us = argc > 3 ? (unsigned)atoi(argv[3]) : 0;  /* for a slow PC master */
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    so.node = (byte)atoi(argv[2]);
    int32_t total = 0;
    int err = execSlaveOpen(&slave, argv[1], &po, &so, handle, &total);
    if (err) {
        fprintf(stderr, "%s: %s\n", argv[1], fap_port_strerror(err));
        return 1;
    }
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    while ((err = execSlaveServe(slave, -1)) >= 0)
        ;
    execSlaveStats st;
    execSlaveGetStats(slave, &st);
    printf("processed %llu, resent %llu, corrupt %llu\n", (unsigned long long)st.processed,
           (unsigned long long)st.resent, (unsigned long long)st.corrupt);
    execSlaveClose(slave);
    return 0;
}
