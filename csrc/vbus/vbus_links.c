/* vbus_links.c - where the virtual bus's port links live: their
 * directory, and the links of buses still open at exit. */
#include "vbus/vbus_internal.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

int lf_vbus_make_dir(fap_vbus *b, const char *link_dir)
{
    if (link_dir) {
        if (!*link_dir)
            return -EINVAL;
        b->dir = strdup(link_dir);
        if (!b->dir)
            return -ENOMEM;
        if (mkdir(link_dir, 0755) == 0)
            b->own_dir = 1;
        else if (errno != EEXIST)
            return -errno;
        return 0;
    }
    const char *tmp = getenv("TMPDIR");
    if (asprintf(&b->dir, "%s/fap-vbus-XXXXXX", tmp && *tmp ? tmp : "/tmp") < 0) {
        b->dir = NULL;
        return -ENOMEM;
    }
    if (!mkdtemp(b->dir))
        return -errno;
    b->own_dir = 1;
    return 0;
}

/* ---- links of buses still open at exit ------------------------------------
 * A program that exits without fap_vbus_close (a failed test, exit() from
 * a CLI) would leave its symlinks and temp dir behind. An atexit handler
 * removes those of the buses this process opened; fork children leave
 * their parent's alone. Only paths are touched: no threads, no fds. */

static pthread_mutex_t live_mu = PTHREAD_MUTEX_INITIALIZER;
static fap_vbus *live_head;
static pthread_once_t live_once = PTHREAD_ONCE_INIT;

void lf_vbus_remove_links(fap_vbus *b)
{
    for (unsigned i = 0; i < FAP_VBUS_MAX_PORTS; i++)
        if (b->port[i].link)
            unlink(b->port[i].link);
    if (b->own_dir && b->dir)
        rmdir(b->dir);
}

static void live_atexit(void)
{
    /* trylock: a fork child may have inherited the lock held by a thread
     * that no longer exists; then leave the cleanup to the parent */
    if (pthread_mutex_trylock(&live_mu) != 0)
        return;
    for (fap_vbus *b = live_head; b; b = b->live_next)
        if (b->owner == getpid())
            lf_vbus_remove_links(b);
    pthread_mutex_unlock(&live_mu);
}

static void live_init(void)
{
    atexit(live_atexit);
}

void lf_vbus_live_add(fap_vbus *b)
{
    pthread_once(&live_once, live_init);
    pthread_mutex_lock(&live_mu);
    b->live_next = live_head;
    live_head = b;
    pthread_mutex_unlock(&live_mu);
}

void lf_vbus_live_remove(fap_vbus *b)
{
    pthread_mutex_lock(&live_mu);
    for (fap_vbus **pp = &live_head; *pp; pp = &(*pp)->live_next) {
        if (*pp == b) {
            *pp = b->live_next;
            break;
        }
    }
    pthread_mutex_unlock(&live_mu);
}

