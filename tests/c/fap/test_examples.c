/* Runs the UNCHANGED example programs (examples/fap/fap_master.c and
 * fap_slave.c, linked against the shared libfap like a user's program) on
 * two ports of a virtual bus and checks that they exchanged data:
 *   test_fap_examples MASTER_BIN SLAVE_BIN */
#include "bus_util.h"
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

static const char *master_bin, *slave_bin;

/* Start argv with stdout on a pipe; returns pid, *out the read end. */
static pid_t spawn(char *const argv[], int *out)
{
    int p[2];
    if (pipe2(p, O_CLOEXEC) < 0)
        return -1;
    pid_t pid = fork();
    if (pid == 0) {
        dup2(p[1], STDOUT_FILENO);
        execv(argv[0], argv);
        _exit(127);
    }
    close(p[1]);
    *out = p[0];
    return pid;
}

/* Read from fd into buf (appending) until `needle` appears or timeout. */
static int read_until(int fd, char *buf, size_t cap, const char *needle, int timeout_ms)
{
    size_t n = strlen(buf);
    int64_t end = fap_port_now_ns() + (int64_t)timeout_ms * 1000000;
    while (!strstr(buf, needle)) {
        int left = (int)((end - fap_port_now_ns()) / 1000000);
        struct pollfd pf = { .fd = fd, .events = POLLIN };
        if (left <= 0 || poll(&pf, 1, left) <= 0)
            return -1;
        ssize_t r = read(fd, buf + n, cap - 1 - n);
        if (r <= 0)
            return strstr(buf, needle) ? 0 : -1;
        n += (size_t)r;
        buf[n] = 0;
    }
    return 0;
}

static void test_examples_exchange(void)
{
    fap_vbus *bus = open_bus(3, 0);
    REQUIRE(bus);
    char *sargv[] = { (char *)slave_bin, (char *)fap_vbus_port_path(bus, 1), "7", NULL };
    char *margv[] = { (char *)master_bin, (char *)fap_vbus_port_path(bus, 0), "7", "5", NULL };
    static char sout[65536], mout[65536];
    int sfd, mfd;
    pid_t spid = spawn(sargv, &sfd);
    REQUIRE(spid > 0);
    CHECK_EQ(read_until(sfd, sout, sizeof sout, "slave 7 ready", 10000), 0);
    pid_t mpid = spawn(margv, &mfd);
    REQUIRE(mpid > 0);
    CHECK_EQ(read_until(mfd, mout, sizeof mout, "master: ", 30000), 0);
    read_until(mfd, mout, sizeof mout, "\n\n", 2000);       /* rest of the output, till EOF */
    int st = -1;
    waitpid(mpid, &st, 0);
    CHECK(WIFEXITED(st) && WEXITSTATUS(st) == 0);
    CHECK(strstr(mout, "master: 5 of 5 replies") != NULL);
    CHECK(strstr(mout, "reply from 7: slave 7 got: hello 0 from the master") != NULL);
    CHECK(strstr(mout, "reply from 7: slave 7 got: hello 4 from the master") != NULL);
    CHECK_EQ(read_until(sfd, sout, sizeof sout, "received from 0: hello 4", 5000), 0);
    CHECK(strstr(sout, "slave 7 received from 0: hello 0 from the master") != NULL);
    kill(spid, SIGTERM);
    waitpid(spid, NULL, 0);
    close(sfd);
    close(mfd);
    if (strstr(mout, "master: 5 of 5") == NULL)
        fprintf(stderr, "master said:\n%s\nslave said:\n%s\n", mout, sout);
    fap_vbus_close(bus);
}

static void run(void)
{
    test_examples_exchange();
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: %s MASTER_BIN SLAVE_BIN\n", argv[0]);
        return 2;
    }
    master_bin = argv[1];
    slave_bin = argv[2];
    static const unit_test t[] = { { "test_examples_exchange", run } };
    return unit_run(t, 1);
}
