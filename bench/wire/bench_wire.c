/* bench_wire: one side of one exchange benchmark on a bus someone else
 * runs (python -m bench opens the virtual bus and starts both sides as
 * separate processes, so each side's CPU is its own and the bus relay's is
 * nobody's).
 *
 *   bench_wire serve KIND PATH[,PATH...] [--baud B] [--same-id]
 *       prints "ready", serves until SIGTERM.  PATHs get slave ids 1, 2, ...
 *       (--same-id: every PATH is its own bus, id 1 on each).
 *   bench_wire client KIND PATH[,PATH...] [--baud B] [--seconds S] [--slaves N]
 *       warms up, prints "measuring", measures S seconds, then prints one
 *       JSON object: exchanges, seconds, cpu_s (this process), wakeups
 *       (voluntary context switches), rss_kib growth per handle,
 *       request/reply bytes per exchange.
 *   bench_wire codec
 *       payload MB/s of the FAP, exec async and mikroC encoders/decoders
 *       (no I/O), one JSON object.
 *
 * KIND: bare (write 15 bytes, read 15: no protocol, the floor of the bus),
 * fap-poll (FAP poll cycles SEND_DATA -> DATA_DONE, slaves with nothing to
 * send; one master per PATH, --slaves ids listed on each), fap-data (FAP
 * DATA 8 bytes, echoed by the slave application), exec (exec async, 8
 * bytes echoed), mikroc (mikroC RS-485, 3 bytes echoed), modbus (libmodbus
 * RTU read of 10 holding registers; only when built with libmodbus). */
#include "exec_async_engine.h"
#include "fap/codec.h"
#include "fap_port.h"
#include "fapx.h"
#include "mikroc_rs485.h"
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <termios.h>
#include <fcntl.h>
#include <unistd.h>
#ifdef HAVE_LIBMODBUS
#include <modbus.h>
#endif

#define MAXP 64
static const char *paths[MAXP];
static int npaths;
static unsigned baud = 115200;
static int paced;               /* --baud given: the bus is paced */
static double seconds = 2.0;
static int nslaves = 1;
static int same_id;

static double now_s(void) { return (double)fap_port_now_ns() / 1e9; }

static double cpu_s(void)
{
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return ru.ru_utime.tv_sec + ru.ru_stime.tv_sec + (ru.ru_utime.tv_usec + ru.ru_stime.tv_usec) / 1e6;
}

/* Voluntary context switches of every thread: how often this process
 * went to sleep and was woken (load-independent, unlike CPU time). */
static long wakeups(void)
{
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return ru.ru_nvcsw;
}

static long rss_kib(void)
{
    FILE *f = fopen("/proc/self/status", "r");
    char line[256];
    long v = 0;
    while (f && fgets(line, sizeof line, f))
        if (sscanf(line, "VmRSS: %ld", &v) == 1)
            break;
    if (f)
        fclose(f);
    return v;
}

static void die(const char *what, int rc)
{
    fprintf(stderr, "bench_wire: %s: %d (%s)\n", what, rc, fap_port_strerror(rc));
    exit(1);
}

static fap_port_options port_opts(void)
{
    fap_port_options po;
    fap_port_options_init(&po);
    po.baud = baud;
    po.rs485_mode = FAP_RS485_NONE;
    return po;
}

/* ---- bare: raw fds, the floor ---- */
#define BARE_N 15
static int bare_open(const char *path)
{
    int fd = open(path, O_RDWR | O_NOCTTY);
    if (fd < 0)
        die("open", -errno);
    struct termios t;
    tcgetattr(fd, &t);
    cfmakeraw(&t);
    tcsetattr(fd, TCSANOW, &t);
    return fd;
}

/* Read exactly n bytes, waking whenever bytes arrive (what a plain
 * blocking reader does); 0, or -1 after 1 s without bytes. */
static int bare_read(int fd, uint8_t *buf, int n)
{
    int got = 0;
    while (got < n) {
        struct pollfd pf = {.fd = fd, .events = POLLIN};
        if (poll(&pf, 1, 1000) <= 0)
            return -1;
        ssize_t r = read(fd, buf + got, (size_t)(n - got));
        if (r <= 0)
            return -1;
        got += (int)r;
    }
    return 0;
}

static void *bare_serve(void *arg)
{
    int fd = bare_open(arg);
    uint8_t buf[BARE_N];
    for (;;)
        if (bare_read(fd, buf, BARE_N) == 0 && write(fd, buf, BARE_N) < 0)
            break;
    return NULL;
}

/* ---- fap ---- */
static fapx *fap_open_node(const char *path, unsigned mode, unsigned id)
{
    fapx_options o;
    fapx_options_init(&o);
    if (paced) {
        /* as bench/fap: a loaded machine can stall a paced frame past 10 ms */
        o.gap_us = 50000;
        o.idc_us = 1000000;
        o.send_budget_us = 1000000;
    }
    o.mode = mode;
    o.id = id;
    o.port = port_opts();
    fapx *h = NULL;
    int rc = fapx_open(&h, path, &o);
    if (rc < 0)
        die("fapx_open", rc);
    return h;
}

static void *fap_echo(void *arg)
{
    fapx *s = arg;
    uint8_t buf[FAPX_MAX_DATA];
    unsigned src;
    for (;;) {
        int n = fapx_rx_wait(s, buf, sizeof buf, &src, 1000);
        if (n > 0)
            fapx_tx_wait(s, src, buf, (size_t)n, 1000);
    }
    return NULL;
}

/* ---- exec async ---- */
static int exec_echo(void *ctx, const execSlaveRequest *req, byte *reply, word cap)
{
    (void)ctx;
    if (req->len > cap)
        return -1;
    memcpy(reply, req->data, req->len);
    return req->len;
}

static void *exec_serve(void *arg)
{
    const char *path = ((const char **)arg)[0];
    unsigned node = (unsigned)(uintptr_t)((const char **)arg)[1];
    fap_port_options po = port_opts();
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    so.node = (byte)node;
    execSlave *s = NULL;
    int rc = execSlaveOpen(&s, path, &po, &so, exec_echo, NULL);
    if (rc < 0)
        die("execSlaveOpen", rc);
    for (;;)
        execSlaveServe(s, 1000);
    return NULL;
}

/* ---- mikroC ---- */
static void *mikroc_serve(void *arg)
{
    const char *path = ((const char **)arg)[0];
    unsigned addr = (unsigned)(uintptr_t)((const char **)arg)[1];
    static __thread mikrocRS485_ctx c;
    mikrocRS485_CtxInitSlave(&c, (uint8_t)addr);
    fap_port_options po = port_opts();
    int rc = mikrocRS485_CtxOpen(&c, path, baud, &po);
    if (rc < 0)
        die("mikrocRS485_CtxOpen", rc);
    char buf[16] = {0};
    for (;;) {
        int m = mikrocRS485_CtxPoll(&c, buf, 1000);
        if (m & MIKROC_RS485_POLL_READY) {
            unsigned n = (unsigned char)buf[MIKROC_RS485_IDX_COUNT];
            buf[MIKROC_RS485_IDX_READY] = 0;
            mikrocRS485_CtxSend(&c, buf, n, (uint8_t)addr);
        } else if (m & MIKROC_RS485_POLL_ERROR) {
            buf[MIKROC_RS485_IDX_ERROR] = 0;
        }
    }
    return NULL;
}

/* ---- libmodbus ---- */
#ifdef HAVE_LIBMODBUS
static modbus_t *mb_open(const char *path)
{
    modbus_t *ctx = modbus_new_rtu(path, (int)baud, 'N', 8, 1);
    if (!ctx || modbus_connect(ctx) < 0)
        die("modbus_connect", -errno);
    modbus_set_slave(ctx, 1);
    return ctx;
}

static void *mb_serve(void *arg)
{
    modbus_t *ctx = mb_open(arg);
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 200, 0);
    uint8_t q[MODBUS_RTU_MAX_ADU_LENGTH];
    for (;;) {
        int rc = modbus_receive(ctx, q);
        if (rc > 0)
            modbus_reply(ctx, q, rc, map);
    }
    return NULL;
}
#endif

static int serve(const char *kind)
{
    sigset_t ss;
    sigemptyset(&ss);
    sigaddset(&ss, SIGTERM);
    sigaddset(&ss, SIGINT);
    pthread_sigmask(SIG_BLOCK, &ss, NULL);   /* the threads inherit it */
    static const char *args[MAXP][2];
    fapx *keep[MAXP];
    for (int i = 0; i < npaths; i++) {
        unsigned id = same_id ? 1 : (unsigned)i + 1;
        args[i][0] = paths[i];
        args[i][1] = (const char *)(uintptr_t)id;
        pthread_t th;
        if (strcmp(kind, "bare") == 0) {
            pthread_create(&th, NULL, bare_serve, (void *)paths[i]);
        } else if (strcmp(kind, "fap-poll") == 0 || strcmp(kind, "fap-data") == 0) {
            keep[i] = fap_open_node(paths[i], FAPX_SLAVE, id);
            pthread_create(&th, NULL, fap_echo, keep[i]);
        } else if (strcmp(kind, "exec") == 0) {
            pthread_create(&th, NULL, exec_serve, args[i]);
        } else if (strcmp(kind, "mikroc") == 0) {
            pthread_create(&th, NULL, mikroc_serve, args[i]);
#ifdef HAVE_LIBMODBUS
        } else if (strcmp(kind, "modbus") == 0) {
            pthread_create(&th, NULL, mb_serve, (void *)paths[i]);
#endif
        } else {
            fprintf(stderr, "bench_wire: unknown or unavailable kind %s\n", kind);
            return 2;
        }
    }
    printf("ready\n");
    fflush(stdout);
    int sig;
    sigwait(&ss, &sig);
    _exit(0);   /* engines still running: no orderly close needed */
}

/* ---- client ---- */
typedef struct client {
    const char *kind;
    int n;                       /* handles */
    int fd[MAXP];
    fapx *fm[MAXP];
    execMaster *em;
    mikrocRS485_ctx mc;
#ifdef HAVE_LIBMODBUS
    modbus_t *mb;
#endif
    int req, rep;                /* bytes on the wire per exchange */
} client;

static void wait_active(fapx *m, unsigned want)
{
    double t0 = now_s();
    while (now_s() - t0 < 30) {
        if ((unsigned)__builtin_popcount(fapx_active_mask(m)) >= want)
            return;
        fapx_event ev;
        fapx_event_wait(m, &ev, 100);
    }
    fprintf(stderr, "bench_wire: slaves never became active\n");
    exit(1);
}

static int client_open(client *c)
{
    fap_port_options po = port_opts();
    if (strcmp(c->kind, "bare") == 0) {
        c->fd[0] = bare_open(paths[0]);
        c->req = c->rep = BARE_N;
    } else if (strncmp(c->kind, "fap-", 4) == 0) {
        c->n = npaths;
        for (int i = 0; i < npaths; i++) {
            c->fm[i] = fap_open_node(paths[i], FAPX_MASTER, 0);
            for (int id = 1; id <= nslaves; id++)
                fapx_add_slave(c->fm[i], (unsigned)id);
        }
        for (int i = 0; i < npaths; i++)
            wait_active(c->fm[i], (unsigned)nslaves);
        /* poll cycle: SEND_DATA + DATA_DONE; data: DATA 8 out, DATA 8 back,
         * each inside its turn (SEND_DATA/DATA_DONE frames too) */
        c->req = c->rep = 15;
        if (strcmp(c->kind, "fap-data") == 0)
            c->req = c->rep = 23 + 15;
    } else if (strcmp(c->kind, "exec") == 0) {
        execMasterOptions mo;
        execMasterOptionsInit(&mo);
        int rc = execMasterOpen(&c->em, paths[0], &po, &mo);
        if (rc < 0)
            die("execMasterOpen", rc);
        c->req = c->rep = 16;    /* DLE STX node seq 8 data DLE ETX crc crc */
    } else if (strcmp(c->kind, "mikroc") == 0) {
        mikrocRS485_CtxInitMaster(&c->mc);
        int rc = mikrocRS485_CtxOpen(&c->mc, paths[0], baud, &po);
        if (rc < 0)
            die("mikrocRS485_CtxOpen", rc);
        c->req = c->rep = 8;     /* START addr DL 3 data CRC STOP */
#ifdef HAVE_LIBMODBUS
    } else if (strcmp(c->kind, "modbus") == 0) {
        c->mb = mb_open(paths[0]);
        c->req = 8;
        c->rep = 25;
#endif
    } else {
        return -1;
    }
    return 0;
}

static uint64_t fap_polls(client *c)
{
    uint64_t p = 0;
    for (int i = 0; i < c->n; i++) {
        fapx_stats st;
        fapx_get_stats(c->fm[i], &st);
        p += st.polls;
    }
    return p;
}

/* One exchange; 0 ok, -1 failed. fap-poll: waits 10 ms (the engines poll
 * on their own; exchanges are counted from the stats). */
static int exchange(client *c)
{
    uint8_t buf[FAPX_MAX_DATA];
    if (strcmp(c->kind, "bare") == 0) {
        memset(buf, 0x55, BARE_N);
        if (write(c->fd[0], buf, BARE_N) != BARE_N)
            return -1;
        return bare_read(c->fd[0], buf, BARE_N);
    }
    if (strcmp(c->kind, "fap-poll") == 0) {
        usleep(100000);   /* the engines poll on their own; count from the stats */
        return 0;
    }
    if (strcmp(c->kind, "fap-data") == 0) {
        unsigned src;
        fapx_tx(c->fm[0], 1, "pingpong", 8);
        int r = fapx_rx_wait(c->fm[0], buf, sizeof buf, &src, 2000);
        return r == 8 ? 0 : -1;
    }
    if (strcmp(c->kind, "exec") == 0) {
        word len = 0;
        int rc = execMasterTransact(c->em, 1, (const byte *)"pingpong", 8, buf, sizeof buf, &len);
        return rc == 0 && len == 8 ? 0 : -1;
    }
    if (strcmp(c->kind, "mikroc") == 0) {
        char rx[16] = {0};
        if (mikrocRS485_CtxSend(&c->mc, "abc", 3, 1) < 0)
            return -1;
        double t0 = now_s();
        while (now_s() - t0 < 1.0) {
            int m = mikrocRS485_CtxPoll(&c->mc, rx, 1000);
            if (m & MIKROC_RS485_POLL_READY)
                return 0;
            if (m & MIKROC_RS485_POLL_ERROR)
                return -1;
        }
        return -1;
    }
#ifdef HAVE_LIBMODBUS
    if (strcmp(c->kind, "modbus") == 0) {
        uint16_t regs[10];
        return modbus_read_registers(c->mb, 0, 10, regs) == 10 ? 0 : -1;
    }
#endif
    return -1;
}

static int run_client(const char *kind)
{
    static client c;
    c.kind = kind;
    long rss0 = rss_kib();
    if (client_open(&c) < 0) {
        fprintf(stderr, "bench_wire: unknown or unavailable kind %s\n", kind);
        return 2;
    }
    long rss1 = rss_kib();
    int handles = c.n ? c.n : 1;
    for (int i = strcmp(kind, "fap-poll") == 0 ? 29 : 0; i < 30; i++)   /* warm up */
        exchange(&c);
    printf("measuring\n");
    fflush(stdout);
    long n = 0, bad = 0;
    uint64_t p0 = c.n ? fap_polls(&c) : 0;
    long w0 = wakeups();
    double c0 = cpu_s(), t0 = now_s(), t;
    while ((t = now_s()) - t0 < seconds) {
        if (exchange(&c) < 0)
            bad++;
        n++;
    }
    double cpu = cpu_s() - c0;
    long wk = wakeups() - w0;
    if (strcmp(kind, "fap-poll") == 0) {
        n = (long)(fap_polls(&c) - p0);
        bad = 0;
    }
    printf("{\"kind\":\"%s\",\"exchanges\":%ld,\"failed\":%ld,\"seconds\":%.6f,\"cpu_s\":%.6f,"
           "\"wakeups\":%ld,\"handles\":%d,\"slaves\":%d,\"rss_kib_per_handle\":%.1f,\"req_bytes\":%d,\"rep_bytes\":%d}\n",
           kind, n - bad, bad, t - t0, cpu, wk, handles, nslaves,
           (double)(rss1 - rss0) / handles, c.req, c.rep);
    fflush(stdout);
    _exit(0);
}

/* ---- codec throughput (no I/O): payload MB/s ---- */
static volatile size_t sink;
static void count_frame(void *ctx, const lf_fap_frame *f, lf_ns now)
{
    (void)now;
    *(size_t *)ctx += f->len;
}

#define TIMED(label, body) do { \
        double t0_ = now_s(), el_; size_t bytes_ = 0; long it_ = 0; \
        do { for (int k_ = 0; k_ < 64; k_++) { body; } it_ += 64; } while ((el_ = now_s() - t0_) < 0.3); \
        printf("%s\"%s\":%.2f", first++ ? "," : "", label, bytes_ / el_ / 1e6); \
        (void)it_; } while (0)

static int run_codec(void)
{
    static uint8_t data[1024], frame[2048];
    for (unsigned i = 0; i < sizeof data; i++)
        data[i] = (uint8_t)(i * 7);
    int first = 0;
    printf("{");
    size_t flen = lf_fap_encode(frame, sizeof frame, LF_FAP_DATA, 1, 0, data, 1024);
    TIMED("fap_encode", { sink += lf_fap_encode(frame, sizeof frame, LF_FAP_DATA, 1, 0, data, 1024); bytes_ += 1024; });
    static lf_fap_decoder d;
    lf_fap_decoder_init(&d, 0);
    TIMED("fap_decode", { size_t got = 0; lf_fap_decoder_feed(&d, frame, flen, 0, count_frame, &got); bytes_ += got; });
    byte eframe[EXEC_ASYNC_MAX_FRAME], ebuf[EXEC_ASYNC_MAX_DATA];
    word elen = execAsyncBufferOut(1, data, eframe, 255, 0);
    TIMED("exec_encode", { sink += execAsyncBufferOut(1, data, eframe, 255, 0); bytes_ += 255; });
    struct execAsyncStateDef st;
    memset(&st, 0, sizeof st);
    TIMED("exec_decode", { for (word i = 0; i < elen; i++) if (execAsyncByteIn(eframe[i], &st, ebuf)) bytes_ += st.Length; });
    uint8_t mframe[16];
    int mlen = mikrocRS485_Encode(mframe, data, 3, 1, 1);
    TIMED("mikroc_encode", { sink += (size_t)mikrocRS485_Encode(mframe, data, 3, 1, 1); bytes_ += 3; });
    mikrocRS485_decoder md;
    mikrocRS485_DecoderInit(&md);
    mikrocRS485_frame mf;
    TIMED("mikroc_decode", { for (int i = 0; i < mlen; i++) if (mikrocRS485_DecoderFeed(&md, mframe[i], &mf) == MIKROC_RS485_FRAME) bytes_ += mf.count; });
    printf("}\n");
    return 0;
}

int main(int argc, char **argv)
{
    if (argc == 2 && strcmp(argv[1], "codec") == 0)
        return run_codec();
    if (argc < 4) {
        fprintf(stderr, "usage: bench_wire serve|client KIND PATH[,PATH...] [--baud B] "
                        "[--seconds S] [--slaves N] [--same-id]\n");
        return 2;
    }
    static char pathbuf[8192];
    snprintf(pathbuf, sizeof pathbuf, "%s", argv[3]);
    for (char *s = strtok(pathbuf, ","); s && npaths < MAXP; s = strtok(NULL, ","))
        paths[npaths++] = s;
    for (int i = 4; i < argc; i++) {
        if (strcmp(argv[i], "--baud") == 0 && i + 1 < argc) {
            baud = (unsigned)atoi(argv[++i]);
            paced = 1;
        } else if (strcmp(argv[i], "--seconds") == 0 && i + 1 < argc) {
            seconds = atof(argv[++i]);
        } else if (strcmp(argv[i], "--slaves") == 0 && i + 1 < argc) {
            nslaves = atoi(argv[++i]);
        } else if (strcmp(argv[i], "--same-id") == 0) {
            same_id = 1;
        } else if (strcmp(argv[i], "--unpaced") == 0) {
            paced = 0;
        } else {
            fprintf(stderr, "bench_wire: unknown option %s\n", argv[i]);
            return 2;
        }
    }
    if (strcmp(argv[1], "serve") == 0)
        return serve(argv[2]);
    if (strcmp(argv[1], "client") == 0)
        return run_client(argv[2]);
    fprintf(stderr, "bench_wire: serve or client\n");
    return 2;
}
