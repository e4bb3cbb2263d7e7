/* exec async on a virtual bus, no hardware needed: one slave thread, one
 * master, one lost reply. Usage: exec_demo */
#include <pthread.h>
#include <stdio.h>
#include <string.h>

#include <exec_async_engine.h>
#include <fap_vbus.h>

static int applied;

static int echo_upper(void *ctx, const execSlaveRequest *req, byte *reply, word cap)
{
    (void)ctx;
    (void)cap;
    __atomic_fetch_add(&applied, 1, __ATOMIC_RELAXED);
    for (word i = 0; i < req->len; i++)
        reply[i] = (byte)(req->data[i] >= 'a' && req->data[i] <= 'z' ? req->data[i] - 32 : req->data[i]);
    return req->len;
}

static void *serve(void *s)
{
    while (execSlaveServe(s, -1) >= 0)
        ;
    return NULL;
}

int main(void)
{
    fap_vbus *bus;
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    if (fap_vbus_open(&bus, &bo)) {
        fprintf(stderr, "cannot open a virtual bus\n");
        return 1;
    }
    fap_port_options po;
    fap_port_options_init(&po);
    po.rs485_mode = FAP_RS485_NONE;
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    so.node = 7;
    execSlave *s = NULL;
    execMaster *m = NULL;
    if (execSlaveOpen(&s, fap_vbus_port_path(bus, 1), &po, &so, echo_upper, NULL) ||
        execMasterOpen(&m, fap_vbus_port_path(bus, 0), &po, NULL)) {
        fprintf(stderr, "cannot open the ports\n");
        execSlaveClose(s);        /* close what was opened, on every path */
        fap_vbus_close(bus);
        return 1;
    }
    pthread_t t;
    pthread_create(&t, NULL, serve, s);
    const char *words[] = {"hello", "exec", "async"};
    for (int i = 0; i < 3; i++) {
        if (i == 2)
            fap_vbus_drop_next(bus, 1, 13);   /* lose the slave's reply once (13-byte frame) */
        byte reply[EXEC_ASYNC_MAX_DATA];
        word rlen = 0;
        int err = execMasterTransact(m, 7, (const byte *)words[i], (word)strlen(words[i]), reply,
                                     sizeof reply, &rlen);
        printf("%-6s -> %.*s (%s)\n", words[i], (int)rlen, (const char *)reply,
               err ? fap_port_strerror(err) : "ok");
    }
    execMasterStats ms;
    execMasterGetStats(m, &ms);
    printf("master: %llu transactions, %llu retries; slave handler ran %d times\n",
           (unsigned long long)ms.transactions, (unsigned long long)ms.retries,
           __atomic_load_n(&applied, __ATOMIC_RELAXED));
    execSlaveStop(s);
    pthread_join(t, NULL);
    execSlaveClose(s);
    execMasterClose(m);
    fap_vbus_close(bus);
    return 0;
}
