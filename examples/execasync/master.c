/* exec async master: polls one node with a packed command, prints the
 * unpacked reading. Usage: exec_master DEVICE NODE [COUNT] */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <exec_async_engine.h>

#include "reading.h"

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: %s DEVICE NODE [COUNT]\n", argv[0]);
        return 2;
    }
    int node = atoi(argv[2]), count = argc > 3 ? atoi(argv[3]) : 5;
    fap_port_options po;
    fap_port_options_init(&po);             /* 115200 8N1, RS-485 auto */
    execMasterOptions mo;
    execMasterOptionsInit(&mo);
    mo.reply_timeout_us = 200000;
    execMaster *m;
    int err = execMasterOpen(&m, argv[1], &po, &mo);
    if (err) {
        fprintf(stderr, "%s: %s\n", argv[1], fap_port_strerror(err));
        return 1;
    }
    for (int i = 0; i < count; i++) {
        struct command cmd = {.code = 1, .channel = (word)i};
        byte wire[sizeof cmd], reply[EXEC_ASYNC_MAX_DATA];
        word n = execPackDataEx(wire, (byte *)&cmd, command_desc), rlen;
        err = execMasterTransact(m, (byte)node, wire, n, reply, sizeof reply, &rlen);
        if (err) {
            fprintf(stderr, "node %d: %s\n", node, fap_port_strerror(err));
            continue;
        }
        struct reading r;
        memset(&r, 0, sizeof r);
        if (rlen != 13) {
            fprintf(stderr, "node %d: %u-byte reply, expected 13\n", node, rlen);
            continue;
        }
        execUnPackDataEx((byte *)&r, reply, reading_desc);
        printf("node %d channel %u raw %u total %ld delta %d %d %d\n", node, r.channel, r.raw,
               (long)r.total, r.delta[0], r.delta[1], r.delta[2]);
    }
    execMasterStats st;
    execMasterGetStats(m, &st);
    printf("%llu transactions, %llu retries, %llu failures\n",
           (unsigned long long)st.transactions, (unsigned long long)st.retries,
           (unsigned long long)st.failures);
    execMasterClose(m);
    return 0;
}
