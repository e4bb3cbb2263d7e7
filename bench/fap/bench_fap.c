/* FAP benchmark on the virtual bus, all in one run:
 *   1. unpaced: full poll cycles/s (SEND_DATA -> DATA_DONE, no data),
 *      master and one slave on two ports;
 *   2. unpaced: DATA round trips/s (master DATA -> slave app -> reply DATA);
 *   3. the peer: a libmodbus RTU client/server pair on two ports of the same
 *      kind of bus (requests/s), when libmodbus was found at build time;
 *   4. paced at 115200 baud: payload goodput (1024-byte DATA) against the
 *      wire's 11,520 bytes/s and FAP's own framing limit
 *      payload / (payload + 15 per DATA + 30 per SEND_DATA/DATA_DONE turn).
 * Usage: bench_fap [--seconds S]   (default 3 s per measurement) */
#include "fapx.h"
#include "fap_vbus.h"
#include <errno.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#ifdef HAVE_LIBMODBUS
#include <modbus.h>
#endif

static double seconds = 3.0;
static int baud_paced;          /* the bus is paced (set per measurement) */

static double median(double *v, int n)
{
    for (int i = 1; i < n; i++)
        for (int j = i; j > 0 && v[j - 1] > v[j]; j--) {
            double t = v[j];
            v[j] = v[j - 1];
            v[j - 1] = t;
        }
    return n % 2 ? v[n / 2] : (v[n / 2 - 1] + v[n / 2]) / 2;
}

static double now_s(void)
{
    return (double)fap_port_now_ns() / 1e9;
}

static fap_vbus *open_bus(unsigned ports, unsigned baud)
{
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    bo.n_ports = ports;
    bo.baud = baud;
    fap_vbus *bus = NULL;
    int rc = fap_vbus_open(&bus, &bo);
    if (rc < 0) {
        fprintf(stderr, "fap_vbus_open: %d\n", rc);
        exit(1);
    }
    return bus;
}

static fapx *open_node(fap_vbus *bus, unsigned port, unsigned mode, unsigned id, unsigned baud)
{
    fapx_options o;
    fapx_options_init(&o);
    if (baud_paced) {
        /* A virtual bus on a loaded machine can stall a frame for more than
         * the 10 ms default gap (a real UART does not): allow 50 ms, and
         * retry a lost first QUERY_ID after 1 s instead of 15 s. */
        o.gap_us = 50000;
        o.idc_us = 1000000;
        /* 1 s turns instead of 10 s, so a measurement window spans many
         * turns and pays their SEND_DATA/DATA_DONE overhead honestly. */
        o.send_budget_us = 1000000;
    }
    o.mode = mode;
    o.id = id;
    o.port.rs485_mode = FAP_RS485_NONE;
    o.port.baud = baud;
    fapx *h = NULL;
    int rc = fapx_open(&h, fap_vbus_port_path(bus, port), &o);
    if (rc < 0) {
        fprintf(stderr, "fapx_open(%s): %s\n", fap_vbus_port_path(bus, port), fapx_strerror(rc));
        exit(1);
    }
    return h;
}

static void wait_active(fapx *m, unsigned id)
{
    fapx_event ev;
    while (fapx_event_wait(m, &ev, 20000) == 0)
        if (ev.type == FAPX_EV_SLAVE_ACTIVE && ev.id == id)
            return;
    fprintf(stderr, "slave %u never became active\n", id);
    exit(1);
}

/* ---- 1. poll cycles ---- */
typedef struct { fap_vbus *bus; fapx *m, *s; } fap_pair;

static void fap_pair_open(fap_pair *p)
{
    p->bus = open_bus(2, 0);
    p->m = open_node(p->bus, 0, FAPX_MASTER, 0, 115200);
    p->s = open_node(p->bus, 1, FAPX_SLAVE, 1, 115200);
}

static void fap_pair_close(fap_pair *p)
{
    fapx_close(p->s);
    fapx_close(p->m);
    fap_vbus_close(p->bus);
}

/* Poll cycles/s over `secs`: the slave is listed only while measuring, so
 * the bus is quiet while the peer is measured. */
static double measure_cycles(fap_pair *p, double secs)
{
    fapx_add_slave(p->m, 1);
    wait_active(p->m, 1);
    fapx_stats a, b;
    fapx_get_stats(p->m, &a);
    double t0 = now_s();
    fapx_event ev;
    while (now_s() - t0 < secs)         /* the engines run on their own */
        fapx_event_wait(p->m, &ev, (int)((secs - (now_s() - t0)) * 1000) + 1);
    fapx_get_stats(p->m, &b);
    double dt = now_s() - t0;
    fapx_remove_slave(p->m, 1);
    return (double)(b.polls - a.polls) / dt;
}

static double bench_cycles(void)
{
    fap_pair p;
    fap_pair_open(&p);
    double r = measure_cycles(&p, seconds);
    fap_pair_close(&p);
    return r;
}

/* ---- 2. DATA round trips ---- */
static atomic_int echo_stop;
static void *echo_main(void *arg)
{
    fapx *s = arg;
    uint8_t buf[FAPX_MAX_DATA];
    unsigned src;
    while (!atomic_load(&echo_stop)) {
        int n = fapx_rx_wait(s, buf, sizeof buf, &src, 100);
        if (n > 0)
            fapx_tx_wait(s, src, buf, (size_t)n, 1000);
    }
    return NULL;
}

static double bench_round_trips(double *us_per)
{
    fap_vbus *bus = open_bus(2, 0);
    fapx *m = open_node(bus, 0, FAPX_MASTER, 0, 115200);
    fapx *s = open_node(bus, 1, FAPX_SLAVE, 1, 115200);
    fapx_add_slave(m, 1);
    wait_active(m, 1);
    pthread_t th;
    atomic_store(&echo_stop, 0);
    pthread_create(&th, NULL, echo_main, s);
    uint8_t msg[8] = "pingpong", buf[FAPX_MAX_DATA];
    unsigned src;
    long n = 0, bad = 0;
    double t0 = now_s(), t;
    while ((t = now_s()) - t0 < seconds) {
        fapx_tx(m, 1, msg, sizeof msg);
        int r = fapx_rx_wait(m, buf, sizeof buf, &src, 2000);
        if (r != (int)sizeof msg || src != 1 || memcmp(buf, msg, sizeof msg) != 0)
            bad++;
        n++;
    }
    atomic_store(&echo_stop, 1);
    pthread_join(th, NULL);
    fapx_close(s);
    fapx_close(m);
    fap_vbus_close(bus);
    if (bad)
        fprintf(stderr, "round trips: %ld bad replies\n", bad);
    *us_per = (t - t0) / (double)n * 1e6;
    return (double)n / (t - t0);
}

/* ---- 3. libmodbus peer ---- */
#ifdef HAVE_LIBMODBUS
static atomic_int mb_stop;
static void *mb_server(void *arg)
{
    modbus_t *ctx = arg;
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 200, 0);
    uint8_t q[MODBUS_RTU_MAX_ADU_LENGTH];
    modbus_set_indication_timeout(ctx, 0, 100000);
    while (!atomic_load(&mb_stop)) {
        int rc = modbus_receive(ctx, q);
        if (rc > 0)
            modbus_reply(ctx, q, rc, map);
    }
    modbus_mapping_free(map);
    return NULL;
}

typedef struct { fap_vbus *bus; modbus_t *srv, *cli; pthread_t th; } mb_pair;

static int mb_pair_open(mb_pair *p)
{
    p->bus = open_bus(2, 0);
    p->srv = modbus_new_rtu(fap_vbus_port_path(p->bus, 1), 115200, 'N', 8, 1);
    p->cli = modbus_new_rtu(fap_vbus_port_path(p->bus, 0), 115200, 'N', 8, 1);
    if (!p->srv || !p->cli || modbus_connect(p->srv) < 0 || modbus_connect(p->cli) < 0) {
        fprintf(stderr, "libmodbus connect failed: %s\n", modbus_strerror(errno));
        return -1;
    }
    modbus_set_slave(p->srv, 1);
    modbus_set_slave(p->cli, 1);
    atomic_store(&mb_stop, 0);
    pthread_create(&p->th, NULL, mb_server, p->srv);
    return 0;
}

static void mb_pair_close(mb_pair *p)
{
    atomic_store(&mb_stop, 1);
    pthread_join(p->th, NULL);
    modbus_close(p->cli);
    modbus_close(p->srv);
    modbus_free(p->cli);
    modbus_free(p->srv);
    fap_vbus_close(p->bus);
}

static double measure_modbus(mb_pair *p, int nregs, double secs)
{
    uint16_t regs[125];
    long n = 0, bad = 0;
    double t0 = now_s(), t;
    while ((t = now_s()) - t0 < secs) {
        if (modbus_read_registers(p->cli, 0, nregs, regs) != nregs)
            bad++;
        n++;
    }
    if (bad)
        fprintf(stderr, "libmodbus: %ld failed requests\n", bad);
    return (double)(n - bad) / (t - t0);
}

static double bench_modbus(int nregs)
{
    mb_pair p;
    if (mb_pair_open(&p) < 0)
        return 0;
    double r = measure_modbus(&p, nregs, seconds);
    mb_pair_close(&p);
    return r;
}
#endif

/* ---- 4. paced goodput ---- */
typedef struct { fapx *h; unsigned dst; atomic_int stop; } feeder;
static void *feed_main(void *arg)
{
    feeder *f = arg;
    uint8_t payload[FAPX_MAX_DATA];
    for (int i = 0; i < FAPX_MAX_DATA; i++)
        payload[i] = (uint8_t)(i * 31);
    while (!atomic_load(&f->stop))
        fapx_tx_wait(f->h, f->dst, payload, sizeof payload, 100);
    return NULL;
}

typedef struct { double goodput, limit, frames_per_turn, turns; uint64_t lost, dd_timeouts; } paced_result;

/* from_master: the master's slot carries the data; else the slave's turn. */
static paced_result bench_paced(int from_master)
{
    baud_paced = 1;
    fap_vbus *bus = open_bus(2, 115200);
    fapx *m = open_node(bus, 0, FAPX_MASTER, 0, 115200);
    fapx *s = open_node(bus, 1, FAPX_SLAVE, 1, 115200);
    fapx_add_slave(m, 1);
    wait_active(m, 1);
    fapx *tx = from_master ? m : s, *rx = from_master ? s : m;
    feeder f = { .h = tx, .dst = from_master ? 1 : 0 };
    pthread_t th;
    pthread_create(&th, NULL, feed_main, &f);
    uint8_t buf[FAPX_MAX_DATA];
    unsigned src;
    /* warm up: first frame through, then measure whole frames */
    fapx_rx_wait(rx, buf, sizeof buf, &src, 5000);
    fapx_stats a, b;
    fapx_get_stats(m, &a);
    uint64_t bytes = 0;
    double t0 = now_s(), t, window = seconds < 8 ? 8 : seconds;
    while ((t = now_s()) - t0 < window) {
        int n = fapx_rx_wait(rx, buf, sizeof buf, &src, 1000);
        if (n > 0)
            bytes += (uint64_t)n;
    }
    fapx_get_stats(m, &b);
    fapx_stats rs;
    fapx_get_stats(rx, &rs);
    uint64_t lost = rs.gap_timeouts + rs.crc_errors + rs.framing_errors;
    uint64_t dd = b.data_done_timeouts;
    if (getenv("BENCH_FAP_DEBUG")) {
        fapx_stats ss;
        fap_vbus_stats vs;
        fapx_get_stats(s, &ss);
        fap_vbus_get_stats(bus, &vs);
        fprintf(stderr, "master: frames tx %llu rx %llu polls %llu crc %llu framing %llu gap %llu garbage %llu dd-timeouts %llu\n"
                "slave: frames tx %llu rx %llu crc %llu framing %llu gap %llu garbage %llu\n"
                "vbus: in %llu out %llu collisions %llu dropped %llu\n",
                (unsigned long long)b.frames_tx, (unsigned long long)b.frames_rx,
                (unsigned long long)b.polls, (unsigned long long)b.crc_errors,
                (unsigned long long)b.framing_errors, (unsigned long long)b.gap_timeouts,
                (unsigned long long)b.garbage_bytes, (unsigned long long)b.data_done_timeouts,
                (unsigned long long)ss.frames_tx, (unsigned long long)ss.frames_rx,
                (unsigned long long)ss.crc_errors, (unsigned long long)ss.framing_errors,
                (unsigned long long)ss.gap_timeouts, (unsigned long long)ss.garbage_bytes,
                (unsigned long long)vs.bytes_in, (unsigned long long)vs.bytes_out,
                (unsigned long long)vs.collisions, (unsigned long long)vs.dropped);
    }
    atomic_store(&f.stop, 1);
    pthread_join(th, NULL);
    fapx_close(s);
    fapx_close(m);
    fap_vbus_close(bus);
    baud_paced = 0;
    paced_result r;
    r.goodput = (double)bytes / (t - t0);
    double frames = (double)bytes / FAPX_MAX_DATA;
    double turns = (double)(b.polls - a.polls);
    r.turns = turns;
    r.lost = lost;
    r.dd_timeouts = dd;
    r.frames_per_turn = turns > 0 ? frames / turns : frames;
    double k = r.frames_per_turn;
    r.limit = 11520.0 * (1024.0 * k) / (1039.0 * k + 30.0);
    return r;
}

int main(int argc, char **argv)
{
    const char *only = NULL;          /* --only cycles|rt|modbus|paced (for profiling) */
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--seconds") == 0 && i + 1 < argc)
            seconds = atof(argv[++i]);
        else if (strcmp(argv[i], "--only") == 0 && i + 1 < argc)
            only = argv[++i];
    }
    if (only && strcmp(only, "cycles") == 0) {
        printf("FAP poll cycles, unpaced: %.0f /s\n", bench_cycles());
        return 0;
    }
    if (only && strcmp(only, "paced") == 0) {
        for (int fm = 1; fm >= 0; fm--) {
            paced_result r = bench_paced(fm);
            printf("paced %s: %.0f B/s, %.1f %% of the framing limit\n",
                   fm ? "master->slave" : "slave->master", r.goodput, 100.0 * r.goodput / r.limit);
        }
        return 0;
    }
#ifdef HAVE_LIBMODBUS
    if (only && strcmp(only, "modbus") == 0) {
        printf("libmodbus read 1 register, unpaced: %.0f /s\n", bench_modbus(1));
        return 0;
    }
#endif
    printf("FAP benchmark on the virtual bus (%.1f s per row)\n\n", seconds);
    printf("%-58s %14s\n", "measurement", "result");
    printf("%-58s %14s\n", "-----------", "------");
    /* FAP cycles against the libmodbus peer: alternating short windows on
     * two buses in this run, medians, so that a machine whose load changes
     * during the run does not favour either side. */
    enum { ROUNDS = 11 };
    double win = seconds / 2 > 0.2 ? seconds / 2 : 0.2;
    double fc[ROUNDS];
    fap_pair fp;
    fap_pair_open(&fp);
#ifdef HAVE_LIBMODBUS
    double mc[ROUNDS], ratio[ROUNDS];   /* the peer's table lines only */
    mb_pair mp;
    int have_mb = mb_pair_open(&mp) == 0;
#endif
    for (int r = 0; r < ROUNDS; r++) {
        fc[r] = measure_cycles(&fp, win);
#ifdef HAVE_LIBMODBUS
        mc[r] = have_mb ? measure_modbus(&mp, 1, win) : 0;
        ratio[r] = mc[r] > 0 ? fc[r] / mc[r] : 0;
#endif
    }
    fap_pair_close(&fp);
    double cyc = median(fc, ROUNDS);
    char label[128];
    snprintf(label, sizeof label, "FAP poll cycles, unpaced (median of %d x %.1f s)", ROUNDS, win);
    printf("%-58s %10.0f /s\n", label, cyc);
#ifdef HAVE_LIBMODBUS
    if (have_mb) {
        double mb1 = median(mc, ROUNDS);
        snprintf(label, sizeof label, "libmodbus RTU read 1 reg, unpaced (same windows, peer)");
        printf("%-58s %10.0f /s\n", label, mb1);
        printf("%-58s %10.2f x\n", "FAP poll cycles / libmodbus requests (median of ratios)",
               median(ratio, ROUNDS));
        printf("%-58s %10.0f /s\n", "libmodbus RTU read 123 regs, unpaced (peer)",
               measure_modbus(&mp, 123, seconds));
        mb_pair_close(&mp);
    }
#else
    printf("%-58s %14s\n", "libmodbus peer", "not built");
#endif
    double us;
    double rt = bench_round_trips(&us);
    printf("%-58s %10.0f /s  (%.0f us each)\n", "FAP DATA round trips, unpaced (8 bytes there and back)", rt, us);
    const char *dir[2] = { "slave -> master (slave's turn)", "master -> slave (master's slot)" };
    for (int fm = 1; fm >= 0; fm--) {
        paced_result r = bench_paced(fm);
        snprintf(label, sizeof label, "paced 115200, 1024 B DATA, 1 s turns, %s", dir[fm]);
        printf("%-58s %10.0f B/s\n", label, r.goodput);
        (void)0;
        printf("%-58s %10.1f %%\n", "  of the wire's 11,520 B/s", 100.0 * r.goodput / 11520.0);
        snprintf(label, sizeof label, "  FAP framing limit at %.1f DATA per turn (%.0f turns)",
                 r.frames_per_turn, r.turns);
        printf("%-58s %10.0f B/s\n", label, r.limit);
        printf("%-58s %10.1f %%\n", "  goodput / framing limit", 100.0 * r.goodput / r.limit);
        if (r.lost || r.dd_timeouts)     /* a loaded machine stalled the relay */
            printf("%-58s %6llu / %llu\n", "  frames lost (gap/crc) / DATA_DONE timeouts",
                   (unsigned long long)r.lost, (unsigned long long)r.dd_timeouts);
    }
    return 0;
}
