/* vbus_ports.c - the virtual bus's ports: each one's output queue, who has
 * it open (attach tracking), disconnect and reconnect (vbus_internal.h). */
#include "vbus/vbus_internal.h"

#include <stdio.h>
#include <string.h>
#include <termios.h>
#include <sys/inotify.h>
#include <sys/ioctl.h>
#include <unistd.h>

/* ---- output queues --------------------------------------------------- */

static void outq_push(fap_vbus *b, vbus_port *pt, const uint8_t *d, size_t n)
{
    size_t room = LF_VBUS_OUTQ_CAP - pt->oq_len;
    if (n > room) {
        b->overflow += n - room;
        lf_capture_event(&b->cap, lf_now_ns(), "overflow", "port=%u n=%zu",
                         (unsigned)(pt - b->port), n - room);
        n = room;
    }
    size_t tail = (pt->oq_head + pt->oq_len) % LF_VBUS_OUTQ_CAP;
    size_t first = LF_VBUS_OUTQ_CAP - tail < n ? LF_VBUS_OUTQ_CAP - tail : n;
    memcpy(pt->outq + tail, d, first);
    memcpy(pt->outq, d + first, n - first);
    pt->oq_len += n;
}

/* Write as much of the queue as the master takes. */
void lf_vbus_outq_flush(fap_vbus *b, vbus_port *pt)
{
    while (pt->oq_len && pt->pty.master >= 0) {
        size_t chunk = LF_VBUS_OUTQ_CAP - pt->oq_head;
        if (chunk > pt->oq_len)
            chunk = pt->oq_len;
        ssize_t w = write(pt->pty.master, pt->outq + pt->oq_head, chunk);
        if (w <= 0)
            return;   /* EAGAIN: POLLOUT will call again */
        b->bytes_out += (uint64_t)w;
        pt->oq_head = (pt->oq_head + (size_t)w) % LF_VBUS_OUTQ_CAP;
        pt->oq_len -= (size_t)w;
    }
    if (!pt->oq_len)
        pt->oq_head = 0;
}

void lf_vbus_port_write(fap_vbus *b, vbus_port *pt, const uint8_t *d, size_t n)
{
    if (pt->pty.master < 0)
        return;
    if (b->tracking && !pt->attached)
        return;   /* nobody listens: like a serial line with no device open */
    if (!pt->oq_len) {
        ssize_t w = write(pt->pty.master, d, n);
        if (w > 0) {
            b->bytes_out += (uint64_t)w;
            d += w;
            n -= (size_t)w;
        }
    }
    if (n)
        outq_push(b, pt, d, n);
}

/* ---- attach tracking ----------------------------------------------------
 * A port nobody has open receives nothing (else bytes would pile up in the
 * pty and in our queue and greet the next opener, even after its tcflush).
 * The relay drains these events before every delivery decision, so an
 * open that happened before a byte was read is always known. */

static void outq_discard(vbus_port *pt)
{
    pt->oq_head = pt->oq_len = 0;
}

void lf_vbus_attach_events(fap_vbus *b)
{
    union {
        struct inotify_event ev;
        char raw[4096];
    } buf;
    while (b->tracking) {
        ssize_t r = read(b->infd, buf.raw, sizeof buf.raw);
        if (r <= 0)
            return;   /* EAGAIN: all caught up */
        for (char *p = buf.raw; p < buf.raw + r;) {
            struct inotify_event *e = (struct inotify_event *)(void *)p;
            p += sizeof *e + e->len;
            if (e->mask & IN_Q_OVERFLOW) {
                b->tracking = 0;   /* lost count: treat every port as attached */
                return;
            }
            for (unsigned i = 0; i < b->n_ports; i++) {
                vbus_port *pt = &b->port[i];
                if (pt->pty.wd != e->wd || pt->pty.master < 0)
                    continue;
                if (e->mask & IN_OPEN) {
                    if (pt->attached++ == 0) {
                        /* a fresh node: nothing left over from the last one */
                        outq_discard(pt);
                        tcflush(pt->pty.slave, TCIFLUSH);
                    }
                } else if (e->mask & IN_CLOSE) {
                    if (pt->attached > 0 && --pt->attached == 0) {
                        /* the last node left: what it did not read is stale,
                         * and a TIOCEXCL it set (and maybe died with) would
                         * lock out the next one, since we keep the tty open */
                        outq_discard(pt);
                        tcflush(pt->pty.slave, TCIFLUSH);
                        ioctl(pt->pty.slave, TIOCNXCL);
                    }
                }
            }
        }
    }
}

/* Start watching a new pty (before its path is published). */
void lf_vbus_port_watch(fap_vbus *b, vbus_port *pt)
{
    pt->attached = 0;
    if (b->tracking && lf_pty_watch(b->infd, &pt->pty) != 0)
        b->tracking = 0;   /* out of inotify watches: fall back to "all attached" */
}

/* ---- disconnect / reconnect (relay thread only) ----------------------- */

void lf_vbus_port_disconnect(fap_vbus *b, unsigned i, unsigned ms, lf_ns now)
{
    vbus_port *pt = &b->port[i];
    if (pt->pty.master >= 0) {
        /* Re-point the path at a name that does not exist first, so a node
         * that reopens meanwhile gets ENOENT, never a recycled /dev/pts/N. */
        char gone[32];
        snprintf(gone, sizeof gone, ".port%u.disconnected", i);
        lf_symlink_replace(pt->link, gone);
        lf_vbus_attach_events(b);
        lf_pty_unwatch(b->infd, &pt->pty);
        lf_pty_close(&pt->pty);   /* the node's fd hangs up: EIO */
        pt->attached = 0;
        outq_discard(pt);
        lf_wire_set_connected(&b->wire, i, 0);
        b->disconnects++;
    }
    pt->reconnect_at = now + (lf_ns)ms * LF_NS_PER_MS;
    lf_capture_event(&b->cap, now, "disconnect", "port=%u ms=%u", i, ms);
}

void lf_vbus_port_reconnect(fap_vbus *b, unsigned i, lf_ns now)
{
    vbus_port *pt = &b->port[i];
    int err = lf_pty_open(&pt->pty);
    if (!err) {
        lf_vbus_port_watch(b, pt);
        err = lf_symlink_replace(pt->link, pt->pty.name);
    }
    if (err) {
        lf_pty_unwatch(b->infd, &pt->pty);
        lf_pty_close(&pt->pty);
        pt->reconnect_at = now + LF_VBUS_RECONNECT_RETRY_NS;   /* fd shortage: retry */
        return;
    }
    pt->reconnect_at = LF_NEVER;
    lf_wire_set_connected(&b->wire, i, 1);
    lf_capture_event(&b->cap, now, "reconnect", "port=%u", i);
}

