/* Runs examples/mikroc master and slave against each other over a virtual
 * bus (paths of the two programs in $MIKROC_MASTER / $MIKROC_SLAVE). The
 * slave says when it listens; the master starts after that line. */
#include <errno.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include "fap_vbus.h"
#include "fap_port.h"
#include "unit.h"

extern char **environ;

#define WAIT_MS 20000

/* Spawn argv with stdout on a pipe; returns the pid, *out_fd the read end. */
static pid_t spawn_piped(char *const argv[], int *out_fd)
{
    int p[2];
    if (pipe(p) < 0)
        return -1;
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, p[1], STDOUT_FILENO);
    posix_spawn_file_actions_addclose(&fa, p[0]);
    pid_t pid;
    int r = posix_spawn(&pid, argv[0], &fa, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&fa);
    close(p[1]);
    if (r != 0) {
        close(p[0]);
        return -1;
    }
    *out_fd = p[0];
    return pid;
}

/* Append what fd gives to buf until `want` appears or EOF/deadline. */
static int read_until(int fd, char *buf, size_t cap, size_t *len, const char *want,
                      int64_t deadline)
{
    while (!strstr(buf, want)) {
        int64_t left = (deadline - fap_port_now_ns()) / 1000000;
        if (left <= 0)
            return -ETIMEDOUT;
        struct pollfd pf = {.fd = fd, .events = POLLIN};
        if (poll(&pf, 1, (int)left) <= 0)
            continue;
        ssize_t n = read(fd, buf + *len, cap - 1 - *len);
        if (n <= 0)
            return -EPIPE;
        *len += (size_t)n;
        buf[*len] = 0;
    }
    return 0;
}

static int wait_exit(pid_t pid)
{
    int st = 0;
    if (waitpid(pid, &st, 0) != pid)
        return -1;
    return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

static void test_master_and_slave_examples(void)
{
    const char *master = getenv("MIKROC_MASTER"), *slave = getenv("MIKROC_SLAVE");
    REQUIRE(master && slave);
    fap_vbus *bus = NULL;
    fap_vbus_options vo;
    fap_vbus_options_init(&vo);
    vo.n_ports = 2;
    int r = fap_vbus_open(&bus, &vo);
    REQUIRE(r == 0);
    char *sargv[] = {(char *)slave, (char *)fap_vbus_port_path(bus, 1), "115200", "4", NULL};
    char *margv[] = {(char *)master, (char *)fap_vbus_port_path(bus, 0), "115200", "4", NULL};
    int64_t deadline = fap_port_now_ns() + (int64_t)WAIT_MS * 1000000;

    char sout[4096] = "", mout[4096] = "";
    size_t slen = 0, mlen = 0;
    int sfd = -1, mfd = -1;
    pid_t spid = spawn_piped(sargv, &sfd);
    REQUIRE(spid > 0);
    CHECK_EQ(read_until(sfd, sout, sizeof sout, &slen, "listening", deadline), 0);
    pid_t mpid = spawn_piped(margv, &mfd);
    CHECK(mpid > 0);
    if (mpid > 0) {
        /* 0xAA goes out, 0xAB comes back, 0xAC goes out ... */
        CHECK_EQ(read_until(mfd, mout, sizeof mout, &mlen, "says 0xB1", deadline), 0);
        CHECK_EQ(wait_exit(mpid), 0);
        close(mfd);
    }
    CHECK_EQ(read_until(sfd, sout, sizeof sout, &slen, "master says 0xB0", deadline), 0);
    CHECK(strstr(sout, "master says 0xAA") != NULL);
    CHECK(strstr(mout, "slave 160 says 0xAB") != NULL);
    CHECK(strstr(mout, "error") == NULL);
    CHECK_EQ(wait_exit(spid), 0);
    close(sfd);
    fap_vbus_close(bus);
}

UNIT_MAIN(UNIT(test_master_and_slave_examples))
