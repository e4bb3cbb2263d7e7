/* vbus_pty.c - pty pairs (posix_openpt, no libutil) and atomic symlinks. */
#include "vbus/vbus_pty.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/inotify.h>
#include <termios.h>
#include <unistd.h>

int lf_pty_open(lf_pty *p)
{
    p->master = p->slave = p->wd = -1;
    p->name[0] = '\0';
    int m = posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (m < 0)
        return -errno;
    int err = 0;
    if (grantpt(m) != 0 || unlockpt(m) != 0 || ptsname_r(m, p->name, sizeof p->name) != 0) {
        err = errno ? -errno : -EIO;
        close(m);
        return err;
    }
    int s = open(p->name, O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (s < 0) {
        err = -errno;
        close(m);
        return err;
    }
    struct termios tio;
    if (tcgetattr(s, &tio) != 0) {
        err = -errno;
        goto fail;
    }
    cfmakeraw(&tio);
    tio.c_cc[VMIN] = 1;
    tio.c_cc[VTIME] = 0;
    if (tcsetattr(s, TCSANOW, &tio) != 0) {
        err = -errno;
        goto fail;
    }
    p->master = m;
    p->slave = s;
    return 0;
fail:
    close(s);
    close(m);
    return err;
}

void lf_pty_close(lf_pty *p)
{
    if (p->slave >= 0)
        close(p->slave);
    if (p->master >= 0)
        close(p->master);
    p->master = p->slave = -1;
}

int lf_pty_watch(int inotify_fd, lf_pty *p)
{
    p->wd = inotify_add_watch(inotify_fd, p->name, IN_OPEN | IN_CLOSE);
    return p->wd < 0 ? -errno : 0;
}

void lf_pty_unwatch(int inotify_fd, lf_pty *p)
{
    if (p->wd >= 0 && inotify_fd >= 0)
        inotify_rm_watch(inotify_fd, p->wd);
    p->wd = -1;
}

int lf_symlink_replace(const char *link, const char *target)
{
    char tmp[4200];
    static unsigned counter;  /* only makes names unique; races are harmless */
    const char *slash = strrchr(link, '/');
    int dirlen = slash ? (int)(slash - link + 1) : 0;
    int n = snprintf(tmp, sizeof tmp, "%.*s.%s.tmp%ld.%u", dirlen, link,
                     slash ? slash + 1 : link, (long)getpid(),
                     __atomic_fetch_add(&counter, 1, __ATOMIC_RELAXED));
    if (n < 0 || (size_t)n >= sizeof tmp)
        return -ENAMETOOLONG;
    if (symlink(target, tmp) != 0)
        return -errno;
    if (rename(tmp, link) != 0) {
        int err = -errno;
        unlink(tmp);
        return err;
    }
    return 0;
}
