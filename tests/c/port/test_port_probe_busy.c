/* The probe (fap_port_probe, behind `fap ports`) never opens a port that
 * another process holds: every tty open raises RTS, which is the transmit
 * level of an active-low soft-RTS program. A real pty held by fap_port_open
 * (its flock, listed in /proc/locks), watched with inotify: the probe
 * answers -EBUSY and the device node sees no open at all. The lock look-up
 * itself (lf_port_held_elsewhere) against /proc/locks-format files and
 * UUCP lock files. */
#include <signal.h>
#include <stdlib.h>
#include <sys/file.h>
#include <sys/inotify.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/wait.h>

#include "fap_port.h"
#include "port/port_internal.h"
#include "pty_util.h"
#include "unit.h"

/* IN_OPEN events on path from now on: an inotify fd (or -1). */
static int watch_opens(const char *path)
{
    int in = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
    if (in >= 0 && inotify_add_watch(in, path, IN_OPEN) < 0) {
        close(in);
        in = -1;
    }
    return in;
}

/* How many opens inotify reported (non-blocking: events of calls that
 * have returned are queued already). */
static int count_opens(int in)
{
    char buf[4096] __attribute__((aligned(__alignof__(struct inotify_event))));
    int n = 0;
    ssize_t r;
    while ((r = read(in, buf, sizeof buf)) > 0) {
        for (char *p = buf; p < buf + r;) {
            struct inotify_event *e = (struct inotify_event *)p;
            n += (e->mask & IN_OPEN) != 0;
            p += sizeof *e + e->len;
        }
    }
    return n;
}

static void probe_held_by(int exclusive)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = FAP_RS485_NONE;
    o.exclusive = exclusive;
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    int in = watch_opens(t.name);
    MUST(in >= 0);
    unsigned baud = 0;
    CHECK_EQ(fap_port_probe(t.name, &baud, NULL, NULL, NULL), -EBUSY);
    CHECK_EQ(count_opens(in), 0);
    /* the holder's line still works */
    CHECK_EQ(fap_port_write(p, "ok", 2), 2);
    char got[2];
    CHECK_EQ(tp_read_exact(t.master, got, 2, 2000), 2);
    fap_port_close(p);
    /* free again: probed (a pty has no RS-485), and inotify saw that open */
    CHECK_EQ(fap_port_probe(t.name, &baud, NULL, NULL, NULL), -ENOTTY);
    CHECK(count_opens(in) >= 1);
    CHECK_EQ(baud, 115200);
    close(in);
    tp_close(&t);
}

static void test_probe_skips_exclusive_holder(void) { probe_held_by(1); }
static void test_probe_skips_shared_holder(void) { probe_held_by(0); }

/* A plain flock of any program (not libfap) counts too, and through a
 * symlink (/dev/serial/by-id/...) as well: the lock is on the inode. */
static void test_probe_skips_foreign_flock_via_symlink(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    char link[64];
    snprintf(link, sizeof link, "/tmp/fap-probe-link-%d", (int)getpid());
    unlink(link);
    MUST(symlink(t.name, link) == 0);
    int fd = open(t.name, O_RDWR | O_NOCTTY | O_NONBLOCK);
    MUST(fd >= 0);
    MUST(flock(fd, LOCK_EX | LOCK_NB) == 0);
    CHECK_EQ(fap_port_probe(link, NULL, NULL, NULL, NULL), -EBUSY);
    close(fd);
    CHECK_EQ(fap_port_probe(link, NULL, NULL, NULL, NULL), -ENOTTY);
    unlink(link);
    tp_close(&t);
}

static void write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

static void test_held_elsewhere_parses_locks_file(void)
{
    char target[64], locks[64], line[256];
    snprintf(target, sizeof target, "/tmp/fap-probe-target-%d", (int)getpid());
    snprintf(locks, sizeof locks, "/tmp/fap-probe-locks-%d", (int)getpid());
    write_file(target, "");
    struct stat st;
    MUST(stat(target, &st) == 0);
    unsigned ma = major(st.st_dev), mi = minor(st.st_dev);
    unsigned long long ino = (unsigned long long)st.st_ino;

    write_file(locks, "");
    CHECK_EQ(lf_port_held_elsewhere(target, locks, NULL), 0);
    snprintf(line, sizeof line, "1: FLOCK  ADVISORY  WRITE 77 %02x:%02x:%llu 0 EOF\n", ma, mi, ino);
    write_file(locks, line);
    CHECK_EQ(lf_port_held_elsewhere(target, locks, NULL), 1);
    /* a process in another pid namespace shows as pid 0; OFD locks as -1 */
    snprintf(line, sizeof line, "garbage\n2: OFDLCK ADVISORY  READ  -1 %02x:%02x:%llu 0 EOF\n", ma, mi, ino);
    write_file(locks, line);
    CHECK_EQ(lf_port_held_elsewhere(target, locks, NULL), 1);
    /* a waiter ("->") holds nothing; another inode is someone else's */
    snprintf(line, sizeof line, "1: -> FLOCK  ADVISORY  WRITE 78 %02x:%02x:%llu 0 EOF\n"
             "2: FLOCK  ADVISORY  WRITE 79 %02x:%02x:%llu 0 EOF\n", ma, mi, ino, ma, mi, ino + 1);
    write_file(locks, line);
    CHECK_EQ(lf_port_held_elsewhere(target, locks, NULL), 0);
    unlink(locks);
    CHECK_EQ(lf_port_held_elsewhere(target, locks, NULL), -ENOENT);
    CHECK_EQ(lf_port_held_elsewhere("/nonexistent/tty", "/proc/locks", NULL), -ENOENT);
    unlink(target);
}

static void test_held_elsewhere_uucp_lock(void)
{
    char dir[64], target[128], lock[160], pid[32];
    snprintf(dir, sizeof dir, "/tmp/fap-probe-lockdir-%d", (int)getpid());
    MUST(mkdir(dir, 0700) == 0);
    snprintf(target, sizeof target, "%s/ttyFAKE0", dir);
    snprintf(lock, sizeof lock, "%s/LCK..ttyFAKE0", dir);
    write_file(target, "");
    CHECK_EQ(lf_port_held_elsewhere(target, "/proc/locks", dir), 0);
    snprintf(pid, sizeof pid, "%10d\n", (int)getpid());   /* ASCII, as minicom */
    write_file(lock, pid);
    CHECK_EQ(lf_port_held_elsewhere(target, "/proc/locks", dir), 1);
    int me = (int)getpid();   /* binary, the old UUCP way */
    FILE *f = fopen(lock, "wb");
    MUST(f != NULL);
    fwrite(&me, sizeof me, 1, f);
    fclose(f);
    CHECK_EQ(lf_port_held_elsewhere(target, "/proc/locks", dir), 1);
    /* a stale lock: its process is gone (a reaped child's pid) */
    pid_t child = fork();
    if (child == 0)
        _exit(0);
    MUST(child > 0);
    waitpid(child, NULL, 0);
    snprintf(pid, sizeof pid, "%10d\n", (int)child);
    write_file(lock, pid);
    CHECK_EQ(lf_port_held_elsewhere(target, "/proc/locks", dir), 0);
    write_file(lock, "not a pid\n");
    CHECK_EQ(lf_port_held_elsewhere(target, "/proc/locks", dir), 0);
    unlink(lock);
    unlink(target);
    rmdir(dir);
}

UNIT_MAIN(UNIT(test_probe_skips_exclusive_holder), UNIT(test_probe_skips_shared_holder),
          UNIT(test_probe_skips_foreign_flock_via_symlink),
          UNIT(test_held_elsewhere_parses_locks_file), UNIT(test_held_elsewhere_uucp_lock))
