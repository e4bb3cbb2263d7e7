/* vbus_pty.h - pseudo-terminal pairs and the stable symlinks that name them. */
#ifndef LF_VBUS_PTY_H
#define LF_VBUS_PTY_H

#include <stddef.h>

typedef struct lf_pty {
    int master;         /* the relay's side: non-blocking, close-on-exec */
    int slave;          /* held open by the relay so the master never hangs up */
    char name[64];      /* /dev/pts/N */
    int wd;             /* inotify watch on name, -1 if none */
} lf_pty;

/* Open a pty pair with its slave in raw mode (a cooked slave echoes every
 * byte back: a storm on a bus). Returns 0 or -errno; nothing stays open on
 * failure. */
int lf_pty_open(lf_pty *p);
void lf_pty_close(lf_pty *p);

/* Watch who opens and closes the slave (inotify IN_OPEN / IN_CLOSE on
 * /dev/pts/N): how the relay knows whether a node is attached. Add the
 * watch before publishing the path, remove it before closing the pty (our
 * own close would count). Returns 0 or -errno. */
int lf_pty_watch(int inotify_fd, lf_pty *p);
void lf_pty_unwatch(int inotify_fd, lf_pty *p);

/* Point the symlink `link` at `target` atomically (symlink to a temporary
 * name in the same directory, then rename over the old link), so a node
 * opening the path sees either the old or the new target, never nothing. */
int lf_symlink_replace(const char *link, const char *target);

#endif
