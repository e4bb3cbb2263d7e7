/* bench_execasync - exec async master <-> slave transactions per second on
 * the virtual bus (ptys + relay thread), unpaced and paced at 115200 baud,
 * against the wire limit and against libmodbus RTU (read holding registers
 * with a reply of the same payload size) on the same kind of bus.
 *
 * Each row: one master, one slave thread (echo handler), N transactions
 * back to back after a warm-up; per-transaction latency p50/p99.
 * Run: bench_execasync [iterations]   (default 2000 unpaced, 100 paced) */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "exec_async_engine.h"
#include "fap_vbus.h"

#ifdef HAVE_LIBMODBUS
#include <modbus.h>
#endif

#define WARMUP 20
#define BAUD 115200

static int64_t now_ns(void) { return fap_port_now_ns(); }

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

typedef struct result {
    double tps;
    double p50_us, p99_us;
    int errors;
} result;

static result summarise(int64_t *lat, int n, int64_t total_ns, int errors)
{
    qsort(lat, (size_t)n, sizeof *lat, cmp_i64);
    result r = {.tps = n * 1e9 / (double)total_ns,
                .p50_us = lat[n / 2] / 1e3,
                .p99_us = lat[(n * 99) / 100] / 1e3,
                .errors = errors};
    return r;
}

static int echo_handler(void *ctx, const execSlaveRequest *req, byte *reply, word cap)
{
    (void)ctx;
    (void)cap;
    memcpy(reply, req->data, req->len);
    return req->len;
}

static void *serve(void *s)
{
    while (execSlaveServe(s, -1) >= 0)
        ;
    return NULL;
}

static int open_bus(fap_vbus **bus, unsigned baud)
{
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    bo.baud = baud;
    return fap_vbus_open(bus, &bo);
}

static result run_exec(unsigned baud, int payload, int n)
{
    result bad = {0, 0, 0, -1};
    fap_vbus *bus;
    if (open_bus(&bus, baud))
        return bad;
    fap_port_options po;
    fap_port_options_init(&po);
    po.rs485_mode = FAP_RS485_NONE;
    po.baud = baud ? baud : BAUD;
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    so.node = 1;
    execSlave *s;
    execMaster *m;
    if (execSlaveOpen(&s, fap_vbus_port_path(bus, 1), &po, &so, echo_handler, NULL)) {
        fap_vbus_close(bus);
        return bad;
    }
    if (execMasterOpen(&m, fap_vbus_port_path(bus, 0), &po, NULL)) {
        execSlaveClose(s);
        fap_vbus_close(bus);
        return bad;
    }
    pthread_t t;
    pthread_create(&t, NULL, serve, s);
    byte req[EXEC_ASYNC_MAX_DATA], reply[EXEC_ASYNC_MAX_DATA];
    memset(req, 0x55, sizeof req);   /* no DLE: frame = payload + 8 */
    int64_t *lat = malloc(sizeof *lat * (size_t)n);
    int errors = 0;
    word rlen;
    for (int i = 0; i < WARMUP; i++)
        errors += execMasterTransact(m, 1, req, (word)payload, reply, sizeof reply, &rlen) != 0;
    int64_t t0 = now_ns();
    for (int i = 0; i < n; i++) {
        int64_t a = now_ns();
        errors += execMasterTransact(m, 1, req, (word)payload, reply, sizeof reply, &rlen) != 0;
        lat[i] = now_ns() - a;
    }
    result r = summarise(lat, n, now_ns() - t0, errors);
    free(lat);
    execSlaveStop(s);
    pthread_join(t, NULL);
    execSlaveClose(s);
    execMasterClose(m);
    fap_vbus_close(bus);
    return r;
}

#ifdef HAVE_LIBMODBUS
typedef struct mb_server { const char *path; unsigned baud; int count; } mb_server;

static void *modbus_server(void *arg)
{
    mb_server *sv = arg;
    modbus_t *ctx = modbus_new_rtu(sv->path, (int)(sv->baud ? sv->baud : BAUD), 'N', 8, 1);
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 200, 0);
    if (!ctx || !map || modbus_set_slave(ctx, 1) || modbus_connect(ctx)) {
        if (map)
            modbus_mapping_free(map);
        if (ctx)
            modbus_free(ctx);
        return NULL;
    }
    modbus_set_indication_timeout(ctx, 2, 0);   /* never hang the benchmark */
    uint8_t q[MODBUS_RTU_MAX_ADU_LENGTH];
    for (int i = 0; i < sv->count; i++) {
        int rc = modbus_receive(ctx, q);
        if (rc > 0)
            modbus_reply(ctx, q, rc, map);
        else if (rc < 0)
            break;
    }
    modbus_close(ctx);
    modbus_mapping_free(map);
    modbus_free(ctx);
    return NULL;
}

static result run_modbus(unsigned baud, int payload, int n)
{
    result bad = {0, 0, 0, -1};
    fap_vbus *bus;
    if (open_bus(&bus, baud))
        return bad;
    mb_server sv = {fap_vbus_port_path(bus, 1), baud, n + WARMUP};
    pthread_t t;
    pthread_create(&t, NULL, modbus_server, &sv);
    modbus_t *ctx = modbus_new_rtu(fap_vbus_port_path(bus, 0), (int)(baud ? baud : BAUD), 'N', 8, 1);
    if (!ctx || modbus_set_slave(ctx, 1) || modbus_connect(ctx)) {
        if (ctx)
            modbus_free(ctx);
        pthread_join(t, NULL);
        fap_vbus_close(bus);
        return bad;
    }
    uint16_t regs[128];
    int nregs = payload / 2;
    int64_t *lat = malloc(sizeof *lat * (size_t)n);
    int errors = 0;
    for (int i = 0; i < WARMUP; i++)
        errors += modbus_read_registers(ctx, 0, nregs, regs) != nregs;
    int64_t t0 = now_ns();
    for (int i = 0; i < n; i++) {
        int64_t a = now_ns();
        errors += modbus_read_registers(ctx, 0, nregs, regs) != nregs;
        lat[i] = now_ns() - a;
    }
    result r = summarise(lat, n, now_ns() - t0, errors);
    free(lat);
    modbus_close(ctx);
    modbus_free(ctx);
    pthread_join(t, NULL);
    fap_vbus_close(bus);
    return r;
}
#endif

/* Transactions per second the wire allows: 10 bits per byte, both frames. */
static double wire_limit(unsigned baud, int bytes)
{
    return baud / 10.0 / bytes;
}

static void row(const char *who, const char *bus, int payload, int bytes, unsigned baud, result r)
{
    if (r.errors < 0) {
        printf("%-16s %-9s %7d %6d   (could not run)\n", who, bus, payload, bytes);
        return;
    }
    double lim = wire_limit(baud ? baud : BAUD, bytes);
    printf("%-16s %-9s %7d %6d %10.0f %9.1f %9.1f %11.0f %7.0f%% %6d\n", who, bus, payload, bytes,
           r.tps, r.p50_us, r.p99_us, lim, 100.0 * r.tps / lim, r.errors);
}

int main(int argc, char **argv)
{
    int n = argc > 1 ? atoi(argv[1]) : 2000;
    int n_paced = argc > 1 ? n : 100;
    if (n < 10)
        n = n_paced = 10;
    printf("exec async master+slave on the virtual bus; %d transactions (%d paced)\n", n, n_paced);
    printf("bytes = request + reply frame bytes; wire limit at %d baud, 10 bits/byte\n"
           "(unpaced ptys are not bound by it: shown for scale)\n\n", BAUD);
    printf("%-16s %-9s %7s %6s %10s %9s %9s %11s %8s %6s\n", "library", "bus", "payload", "bytes",
           "trans/s", "p50 us", "p99 us", "wire lim/s", "of lim", "errors");
    const int payloads[] = {8, 64, 250};
    for (int pass = 0; pass < 2; pass++) {
        unsigned baud = pass ? BAUD : 0;
        const char *bus = pass ? "115200" : "unpaced";
        int count = pass ? n_paced : n;
        for (size_t i = 0; i < sizeof payloads / sizeof payloads[0]; i++) {
            int p = payloads[i];
            row("libfap execasync", bus, p, 2 * (p + 8), baud, run_exec(baud, p, count));
#ifdef HAVE_LIBMODBUS
            /* read p/2 registers: request 8 bytes, reply 5 + p */
            row("libmodbus RTU", bus, p, 8 + 5 + p, baud, run_modbus(baud, p, count));
#endif
        }
    }
#ifndef HAVE_LIBMODBUS
    printf("\n(libmodbus not found at build time: no peer rows)\n");
#endif
    return 0;
}
