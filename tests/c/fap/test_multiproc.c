/* Multi-process bus test: this process owns the virtual bus and runs the
 * master (handle API); slaves 1, 2, 3 and 5 are separate processes
 * (echo_slave, classic API) on their own ports; slave 4 is listed but never
 * exists. Slave 5 is SIGKILLed mid-cycle and started again with the same
 * ID. Checks: right source, in order, nothing twice, nothing corrupted,
 * inactive marking at data_done, recovery after idc. */
#include "bus_util.h"
#include <fcntl.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#define IDC_US   300000
#define IDA_US   50000
#define DONE_US  200000
#define BUDGET_US 40000

static const char *helper;
static fap_vbus *bus;
static fapx *master;
static pid_t pids[6];
static int stdin_w[6];

static pid_t spawn_slave(unsigned id)
{
    int in[2], out[2];
    /* close-on-exec: a later slave must not inherit an earlier one's stdin */
    if (pipe2(in, O_CLOEXEC) < 0 || pipe2(out, O_CLOEXEC) < 0)
        return -1;
    char idbuf[8], a[24], b[24], c[24], d[24];
    snprintf(idbuf, sizeof idbuf, "%u", id);
    snprintf(a, sizeof a, "%u", IDC_US);
    snprintf(b, sizeof b, "%u", IDA_US);
    snprintf(c, sizeof c, "%u", DONE_US);
    snprintf(d, sizeof d, "%u", BUDGET_US);
    const char *path = fap_vbus_port_path(bus, id);
    pid_t pid = fork();
    if (pid == 0) {
        dup2(in[0], STDIN_FILENO);
        dup2(out[1], STDOUT_FILENO);
        close(in[1]);
        close(out[0]);
        execl(helper, helper, path, idbuf, a, b, c, d, (char *)NULL);
        _exit(127);
    }
    close(in[0]);
    close(out[1]);
    stdin_w[id] = in[1];
    /* wait for "ready" (a pipe read, not a sleep) */
    char line[16] = { 0 };
    ssize_t n = read(out[0], line, sizeof line - 1);
    close(out[0]);
    if (n < 5 || strncmp(line, "ready", 5) != 0) {
        fprintf(stderr, "slave %u did not start (%zd)\n", id, n);
        return -1;
    }
    return pid;
}

static void stop_slave(unsigned id, int sig)
{
    if (pids[id] <= 0)
        return;
    if (sig)
        kill(pids[id], sig);
    close(stdin_w[id]);
    waitpid(pids[id], NULL, 0);
    pids[id] = 0;
}

/* Send count messages to each slave in ids and check every echo. */
static int exchange(const unsigned *ids, int nids, int count, int round)
{
    char msg[64];
    int next[6] = { 0 }, bad = 0, got = 0;
    for (int k = 0; k < count; k++) {
        for (int i = 0; i < nids; i++) {
            int n = snprintf(msg, sizeof msg, "r%d>%u#%d", round, ids[i], k);
            while (fapx_tx(master, ids[i], msg, (size_t)n) == -EAGAIN)
                fapx_flush(master, 1000);
        }
    }
    while (got < count * nids) {
        uint8_t buf[FAPX_MAX_DATA + 1];
        unsigned src;
        int n = fapx_rx_wait(master, buf, sizeof buf - 1, &src, 3000);
        if (n < 0) {
            fprintf(stderr, "rx: %s after %d\n", fapx_strerror(n), got);
            return -1;
        }
        buf[n] = 0;
        int r = -1, k = -1;
        unsigned to = 99;
        if (sscanf((char *)buf, "echo:r%d>%u#%d", &r, &to, &k) != 3 || r != round ||
            to != src || src > 5 || k != next[src]++) {
            fprintf(stderr, "bad echo from %u: %s\n", src, buf);
            bad++;
        }
        got++;
    }
    return bad;
}

static void test_bus_with_processes(void)
{
    bus = open_bus(6, 0);
    REQUIRE(bus);
    fapx_options o;
    fast_options(&o, FAPX_MASTER, 0);
    o.idc_us = IDC_US;
    o.id_answer_us = IDA_US;
    o.data_done_us = DONE_US;
    o.send_budget_us = BUDGET_US;
    int rc = fapx_open(&master, fap_vbus_port_path(bus, 0), &o);
    REQUIRE(rc == 0);
    const unsigned live[] = { 1, 2, 3, 5 };
    for (int i = 0; i < 4; i++) {
        pids[live[i]] = spawn_slave(live[i]);
        CHECK(pids[live[i]] > 0);
    }
    for (unsigned id = 1; id <= 5; id++)
        CHECK_EQ(fapx_add_slave(master, id), 0);
    for (int i = 0; i < 4; i++)
        CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, live[i], 3000, NULL), 0);
    CHECK_EQ(wait_event(master, FAPX_EV_ID_TIMEOUT, 4, 3000, NULL), 0);
    CHECK_EQ(fapx_active_mask(master), (1u << 1) | (1u << 2) | (1u << 3) | (1u << 5));

    CHECK_EQ(exchange(live, 4, 50, 1), 0);

    /* slave 5 dies while the bus is busy */
    const unsigned three[] = { 1, 2, 3 };
    char msg[32];
    for (int k = 0; k < 20; k++) {
        int n = snprintf(msg, sizeof msg, "r2>%u#%d", three[k % 3], k / 3);
        fapx_tx(master, three[k % 3], msg, (size_t)n);
    }
    ev_backlog_n = 0;                     /* only events from now on count */
    int64_t t_kill = fap_port_now_ns();
    stop_slave(5, SIGKILL);
    fapx_event inact = { 0 }, act = { 0 };
    CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_INACTIVE, 5, 3000, &inact), 0);
    /* marked inactive data_done after its last SEND_DATA: not before the
     * kill's SEND_DATA could have gone, not much later than data_done */
    int64_t dt = inact.time_ns - t_kill;
    /* exact timing is checked on the fake clock (test_sim); here: not at
     * once, and not long after data_done */
    CHECK(dt >= (int64_t)DONE_US * 1000 / 2);
    CHECK(dt < (int64_t)DONE_US * 1000 + 2000000000LL);
    CHECK_EQ(fapx_slave_active(master, 5), 0);
    /* drain the echoes of the 20 messages (from 1, 2, 3 only) */
    int echoes = 0, bad = 0;
    while (echoes < 20) {
        uint8_t buf[FAPX_MAX_DATA + 1];
        unsigned src;
        int n = fapx_rx_wait(master, buf, sizeof buf - 1, &src, 3000);
        if (n < 0)
            break;
        buf[n] = 0;
        unsigned to = 99;
        int k;
        if (sscanf((char *)buf, "echo:r2>%u#%d", &to, &k) != 2 || to != src || src == 5)
            bad++;
        echoes++;
    }
    CHECK_EQ(echoes, 20);
    CHECK_EQ(bad, 0);

    /* the ID cycle started at once by the timeout finds nobody at 5 */
    CHECK_EQ(wait_event(master, FAPX_EV_ID_TIMEOUT, 5, 3000, NULL), 0);
    /* back with the same ID: active again at the next ID cycle, idc after that one */
    pids[5] = spawn_slave(5);
    CHECK(pids[5] > 0);
    CHECK_EQ(wait_event(master, FAPX_EV_SLAVE_ACTIVE, 5, 10000, &act), 0);
    CHECK(act.time_ns >= inact.time_ns + (int64_t)IDC_US * 1000);
    CHECK(act.time_ns < inact.time_ns + 10000000000LL);

    CHECK_EQ(exchange(live, 4, 30, 3), 0);
    CHECK_EQ(fapx_slave_active(master, 4), 0);

    fapx_stats st;
    fapx_get_stats(master, &st);
    CHECK(st.data_done_timeouts >= 1);
    CHECK(st.id_timeouts >= 2);               /* slave 4, every idc; 5 while dead */
    CHECK_EQ(st.rx_dropped, 0);
    fprintf(stderr, "master: %llu cycles, %llu polls, %llu frames tx, %llu rx, crc %llu, "
            "framing %llu, gap %llu, id timeouts %llu\n",
            (unsigned long long)st.cycles, (unsigned long long)st.polls,
            (unsigned long long)st.frames_tx, (unsigned long long)st.frames_rx,
            (unsigned long long)st.crc_errors, (unsigned long long)st.framing_errors,
            (unsigned long long)st.gap_timeouts, (unsigned long long)st.id_timeouts);

    for (int i = 0; i < 4; i++)
        stop_slave(live[i], 0);
    fapx_close(master);
    fap_vbus_close(bus);
}

static void run(void)
{
    test_bus_with_processes();
}

int main(int argc, char **argv)
{
    helper = argc > 1 ? argv[1] : "./fap_echo_slave";
    signal(SIGPIPE, SIG_IGN);
    static const unit_test t[] = { { "test_bus_with_processes", run } };
    return unit_run(t, 1);
}
