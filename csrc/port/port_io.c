/* port_io.c - fap_port_read / fap_port_write / fap_port_flush: deadline
 * reads, write-all with EINTR and partial writes, RTS switching, echo
 * read-back, turnaround delay, vanished-device detection. */
#include "port/port_internal.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

#include "common/mono_clock.h"

/* ---- fd primitives shared by read, write and echo ----------------------- */

/* One non-blocking read: >0 bytes, 0 when nothing is queued, or a negative
 * error (-EIO when the tty hung up and reads as end of file). */
static ssize_t read_some(fap_port *p, int fd, void *buf, size_t n)
{
    for (;;) {
        ssize_t r = p->be->read(p->ctx, fd, buf, n);
        /* fewer bytes than room, or none: the kernel queue is empty now */
        __atomic_store_n(&p->rx_empty, r < (ssize_t)n, __ATOMIC_RELAXED);
        if (r > 0)
            return r;
        if (r == 0)
            return -EIO;
        if (errno == EINTR)
            continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK)
            return 0;
        return -errno;
    }
}

/* One poll for events on fd, bounded by deadline. Returns 0 with *revents
 * set (0 after a timeout or EINTR: the caller looks again), -ETIMEDOUT if
 * the deadline has already passed, or a negative error (-EBADF: fd closed). */
static int poll_until(fap_port *p, int fd, short events, int64_t deadline, short *revents)
{
    *revents = 0;
    int64_t now = lf_now_ns();
    if (now >= deadline)
        return -ETIMEDOUT;
    /* pf[1]: the owner's cancel fd (lf_port_open_cancellable), if any */
    struct pollfd pf[2] = {{.fd = fd, .events = events},
                           {.fd = p->cancel_fd ? *p->cancel_fd : -1, .events = POLLIN}};
    nfds_t n = p->cancel_fd ? 2 : 1;
    int r = p->be->poll(p->ctx, pf, n, lf_poll_timeout_ms(deadline, now));
    if (r < 0)
        return errno == EINTR ? 0 : -errno;
    if (r > 0 && n == 2 && pf[1].revents)
        return -ECANCELED;
    if (r > 0 && (pf[0].revents & POLLNVAL))
        return -EBADF;
    if (r > 0)
        *revents = pf[0].revents;
    return 0;
}

/* ---- input parked before an echo-suppressed write (rx_mu held) ----------- */

/* Largest backlog we park; beyond it the bytes stay queued in the kernel
 * (and would be taken for echo: reported as a collision, never lost). */
#define PEND_MAX (1u << 20)

static int pend_reserve(fap_port *p, size_t more)
{
    if (p->pend_off && p->pend_len)
        memmove(p->pend, p->pend + p->pend_off, p->pend_len);
    p->pend_off = 0;
    if (p->pend_len + more <= p->pend_cap)
        return 0;
    size_t cap = p->pend_cap ? p->pend_cap : 256;
    while (cap < p->pend_len + more)
        cap *= 2;
    uint8_t *n = realloc(p->pend, cap);
    if (!n)
        return -ENOMEM;
    p->pend = n;
    p->pend_cap = cap;
    return 0;
}

/* Move everything already queued on the device into pend: it arrived
 * before our frame, so it is someone's data, not our echo. */
static int pend_fill(fap_port *p, int fd)
{
    size_t before = p->pend_len;
    int err = 0;
    while (p->pend_len < PEND_MAX) {
        if (pend_reserve(p, 256) < 0)
            break;   /* no memory: leave the rest in the kernel */
        ssize_t r = read_some(p, fd, p->pend + p->pend_len, 256);
        if (r <= 0) {
            err = (int)r;   /* 0: the queue is empty */
            break;
        }
        p->pend_len += (size_t)r;
    }
    if (p->pend_len > before) {
        pthread_mutex_lock(&p->st_mu);
        p->last_rx_ns = lf_now_ns();
        pthread_mutex_unlock(&p->st_mu);
        if (before == 0)
            lf_port_pend_signal(p, 1);
    }
    return err;
}

static size_t pend_take(fap_port *p, void *buf, size_t n)
{
    if (n > p->pend_len)
        n = p->pend_len;
    memcpy(buf, p->pend + p->pend_off, n);
    p->pend_off += n;
    p->pend_len -= n;
    if (p->pend_len == 0) {
        p->pend_off = 0;
        lf_port_pend_signal(p, 0);
    }
    return n;
}

/* ---- echo read-back ----------------------------------------------------- */

typedef struct echo_state {
    const uint8_t *sent;
    size_t n;         /* bytes to read back */
    size_t got;       /* read back so far */
    int mismatch;
} echo_state;

/* Take whatever echo is there now, never more than is still owed: the
 * bytes after our echo (a fast answer) stay in the kernel for the reader. */
static int echo_take(fap_port *p, int fd, echo_state *es)
{
    uint8_t tmp[256];
    while (es->got < es->n) {
        size_t want = es->n - es->got;
        if (want > sizeof tmp)
            want = sizeof tmp;
        ssize_t r = read_some(p, fd, tmp, want);
        if (r <= 0)
            return (int)r;   /* 0: the rest has not arrived yet */
        if (memcmp(tmp, es->sent + es->got, (size_t)r) != 0)
            es->mismatch = 1;
        es->got += (size_t)r;
    }
    return 0;
}

static int echo_finish(fap_port *p, int fd, echo_state *es, int64_t deadline)
{
    for (;;) {
        int err = echo_take(p, fd, es);
        if (err)
            return err;
        if (es->got >= es->n)
            return es->mismatch ? FAP_PORT_ECOLLISION : 0;
        short rev;
        err = poll_until(p, fd, POLLIN, deadline, &rev);
        if (err == -ETIMEDOUT && es->mismatch)
            return FAP_PORT_ECOLLISION;
        if (err)
            return err;
        /* POLLHUP/POLLERR: the read above reports it next round. */
    }
}

/* ---- write ------------------------------------------------------------- */

static int64_t write_deadline(const fap_port *p, size_t n)
{
    if (p->opt.write_timeout_us)
        return lf_now_ns() + (int64_t)p->opt.write_timeout_us * LF_NS_PER_US;
    /* Twice the wire time of the frame plus a second: generous for any
     * real UART, still finite when nobody drains the other end. */
    return lf_now_ns() + 2 * (int64_t)n * lf_char_time_ns(p->opt.baud) + LF_NS_PER_S;
}

static int write_all(fap_port *p, int fd, const uint8_t *buf, size_t n,
                     size_t *written, echo_state *es)
{
    int64_t deadline = write_deadline(p, n);
    size_t off = 0;
    while (off < n) {
        ssize_t w = p->be->write(p->ctx, fd, buf + off, n - off);
        if (w > 0) {
            off += (size_t)w;
            *written = off;
            if (es) {
                int err = echo_take(p, fd, es);
                if (err)
                    return err;
            }
            continue;
        }
        if (w < 0 && errno == EINTR)
            continue;
        if (w < 0 && errno != EAGAIN && errno != EWOULDBLOCK)
            return -errno;
        /* Output queue full: wait for room, consuming echo meanwhile so the
         * input queue cannot fill up and stall a long write. */
        short rev;
        int err = poll_until(p, fd, (short)(POLLOUT | (es ? POLLIN : 0)), deadline, &rev);
        if (err)
            return err;
        if (es && (rev & POLLIN)) {
            err = echo_take(p, fd, es);
            if (err)
                return err;
        }
        if ((rev & (POLLHUP | POLLERR)) && !(rev & (POLLOUT | POLLIN)))
            return -EIO;
    }
    return 0;
}

static int drain(fap_port *p, int fd)
{
    return p->be->drain(p->ctx, fd);
}

/* The drain returns when the driver thinks the transmitter is empty
 * (serial_core: its tx_empty). Where the transport can also tell from the
 * line itself (tx_empty: a device's line status register, TEMT), wait for
 * that too before the direction line drops; bounded by 3 character times
 * + 1 ms. */
static void wait_temt(fap_port *p, int fd)
{
    if (!p->be->tx_empty)
        return;
    int64_t ct = lf_char_time_ns(p->opt.baud);
    int64_t end = lf_now_ns() + 3 * ct + LF_NS_PER_MS;
    while (p->be->tx_empty(p->ctx, fd) == 0 && lf_now_ns() < end)
        p->be->sleep_until(p->ctx, lf_now_ns() + ct / 2);
}

static void wait_turnaround(fap_port *p)
{
    if (!p->opt.turnaround_us)
        return;
    pthread_mutex_lock(&p->st_mu);
    int64_t last = p->last_rx_ns;
    pthread_mutex_unlock(&p->st_mu);
    if (!last)
        return;
    int64_t until = last + (int64_t)p->opt.turnaround_us * LF_NS_PER_US;
    if (until > lf_now_ns())
        p->be->sleep_until(p->ctx, until);
}

static void delay_us(fap_port *p, unsigned us)
{
    if (us)
        p->be->sleep_until(p->ctx, lf_now_ns() + (int64_t)us * LF_NS_PER_US);
}

static int64_t echo_deadline(const fap_port *p, size_t n)
{
    int64_t ct = lf_char_time_ns(p->opt.baud);
    int64_t wait = p->opt.echo_timeout_us
                       ? (int64_t)p->opt.echo_timeout_us * LF_NS_PER_US
                       : 20 * ct + 20 * LF_NS_PER_MS;
    /* The drain on a USB adapter returns before its FIFO is on the wire:
     * allow the frame's own wire time on top. */
    return lf_now_ns() + (int64_t)n * ct + wait;
}

/* lazy_drain: skip the drain when nothing after it depends on the frame
 * having left the UART (no soft RTS to release, no echo to time): the
 * transact path, whose caller waits for the reply anyway. */
static ssize_t port_write(fap_port *p, const void *buf, size_t n, int lazy_drain)
{
    pthread_mutex_lock(&p->tx_mu);
    int fd;
    fap_rs485_mode mode;
    int err = lf_port_acquire(p, &fd, &mode);
    if (err) {
        pthread_mutex_unlock(&p->tx_mu);
        return err;
    }
    wait_turnaround(p);

    int switched = mode == FAP_RS485_SOFT_RTS || mode == FAP_RS485_GPIO;   /* we drive DE */
    echo_state es = {.sent = buf, .n = n};
    int echo = p->opt.echo_suppression;
    size_t written = 0;
    if (echo) {
        pthread_mutex_lock(&p->rx_mu);
        err = pend_fill(p, fd);
        if (err)
            goto out;
    }
    if (switched) {
        err = lf_port_rts(p, fd, &p->conn, 1);   /* conn is stable under tx_mu */
        if (err)
            goto out;   /* nothing sent */
        delay_us(p, p->conn.delay_before_us);
    }
    int64_t t_write = lf_now_ns();
    err = write_all(p, fd, buf, n, &written, echo ? &es : NULL);
    /* the earliest an answer to it can start (rx_pacing.h: lf_port_tx_end_ns) */
    __atomic_store_n(&p->tx_end_ns, t_write + (int64_t)written * lf_char_time_ns(p->opt.baud),
                     __ATOMIC_RELAXED);
    if (!err && (!lazy_drain || echo || switched))
        err = drain(p, fd);   /* the last stop bit has left the UART */
    if (!err && switched)
        wait_temt(p, fd);
    if (switched) {
        if (!err)
            delay_us(p, p->conn.delay_after_us);
        int rerr = lf_port_rts(p, fd, &p->conn, 0);   /* release even after an error */
        if (!err)
            err = rerr;
    }
    if (!err && echo)
        err = echo_finish(p, fd, &es, echo_deadline(p, n));
out:
    if (echo)
        pthread_mutex_unlock(&p->rx_mu);
    lf_port_note_error(p, err);
    pthread_mutex_lock(&p->st_mu);
    p->stats.tx_bytes += written;
    p->stats.echo_bytes += es.got;
    if (err) {
        p->stats.write_errors++;
        if (err == FAP_PORT_ECOLLISION)
            p->stats.collisions++;
    }
    pthread_mutex_unlock(&p->st_mu);
    lf_port_release(p);
    pthread_mutex_unlock(&p->tx_mu);
    return err ? err : (ssize_t)n;
}

ssize_t fap_port_write(fap_port *p, const void *buf, size_t n)
{
    if (!p || (!buf && n) || n > SSIZE_MAX)
        return -EINVAL;
    if (n == 0)
        return 0;
    return port_write(p, buf, n, 0);
}

ssize_t fap_port_send(fap_port *p, const void *buf, size_t n)
{
    if (!p || (!buf && n) || n > SSIZE_MAX)
        return -EINVAL;
    if (n == 0)
        return 0;
    return port_write(p, buf, n, 1);
}

/* ---- read -------------------------------------------------------------- */

/* poll_first: the caller just sent a request, so nothing is there yet:
 * wait before the first read() instead of trying one that fails with EAGAIN. */
static ssize_t port_read(fap_port *p, void *buf, size_t n, int64_t deadline_ns, int poll_first)
{
    if (n > SSIZE_MAX)
        n = SSIZE_MAX;
    int fd;
    int err = lf_port_acquire(p, &fd, NULL);
    if (err)
        return err;
    ssize_t result = 0;
    short hup = 0;
    int parked = 0;
    while (n > 0) {
        /* rx_mu only around read(): a write reading back its echo holds it,
         * so a concurrent reader never sees our own bytes. */
        pthread_mutex_lock(&p->rx_mu);
        if (p->pend_len) {
            result = (ssize_t)pend_take(p, buf, n);
            parked = 1;   /* received earlier: last_rx_ns already set */
        } else if (poll_first == 1) {
            poll_first = 2;   /* skipped: read at least once before giving up */
            result = 0;
        } else {
            result = read_some(p, fd, buf, n);
        }
        pthread_mutex_unlock(&p->rx_mu);
        if (result != 0)
            break;   /* bytes, or an error */
        if (hup) {   /* poll said hang-up and there is nothing to read */
            result = -EIO;
            break;
        }
        short rev;
        err = poll_until(p, fd, POLLIN, deadline_ns, &rev);   /* deadline 0 has passed */
        if (err == -ETIMEDOUT && poll_first == 2) {
            poll_first = 0;
            continue;   /* the read we skipped */
        }
        poll_first = 0;
        if (err) {
            if (err != -ETIMEDOUT)
                result = err;
            break;   /* -ETIMEDOUT: result 0, the deadline */
        }
        if (rev && !(rev & POLLIN))
            hup = rev & (POLLHUP | POLLERR);
    }
    pthread_mutex_lock(&p->st_mu);
    if (result > 0) {
        p->stats.rx_bytes += (uint64_t)result;
        if (!parked)
            p->last_rx_ns = lf_now_ns();
    } else if (result < 0 && result != -ECANCELED) {   /* a stop is no read error */
        p->stats.read_errors++;
    }
    pthread_mutex_unlock(&p->st_mu);
    if (result < 0)
        lf_port_note_error(p, (int)result);
    lf_port_release(p);
    return result;
}

ssize_t fap_port_read(fap_port *p, void *buf, size_t n, int64_t deadline_ns)
{
    if (!p || (!buf && n))
        return -EINVAL;
    /* The last read emptied the queue and the caller will wait: the bytes
     * it waits for are most likely not there yet, so poll first (2
     * syscalls when they come) instead of a read failing with EAGAIN, a
     * poll, then the read (3). Otherwise (deadline 0, or input may be
     * queued) read first. */
    int poll_first = __atomic_load_n(&p->rx_empty, __ATOMIC_RELAXED) &&
                     deadline_ns > lf_now_ns();
    return port_read(p, buf, n, deadline_ns, poll_first);
}

int fap_port_flush(fap_port *p)
{
    if (!p)
        return -EINVAL;
    pthread_mutex_lock(&p->tx_mu);
    pthread_mutex_lock(&p->rx_mu);
    int fd;
    int err = lf_port_acquire(p, &fd, NULL);
    if (!err) {
        if (p->pend_len) {
            p->pend_off = p->pend_len = 0;
            lf_port_pend_signal(p, 0);
        }
        err = p->be->flush(p->ctx, fd, LF_PORT_FLUSH_BOTH);
        if (err)
            lf_port_note_error(p, err);
        lf_port_release(p);
    }
    pthread_mutex_unlock(&p->rx_mu);
    pthread_mutex_unlock(&p->tx_mu);
    return err;
}

/* ---- transact: discard stale input, write, first chunk of the reply ----- */

/* Drop what was received and not read (parked input included) by reading
 * it: unlike a flush this never touches output still queued for the far
 * end (on a pty, a frame not yet taken). One read() when nothing waits;
 * bounded, so a babbling line cannot keep the caller here. */
int fap_port_discard_input(fap_port *p)
{
    if (!p)
        return -EINVAL;
    int fd;
    int err = lf_port_acquire(p, &fd, NULL);
    if (err)
        return err;
    uint8_t tmp[256];
    pthread_mutex_lock(&p->rx_mu);
    if (p->pend_len) {
        p->pend_off = p->pend_len = 0;
        lf_port_pend_signal(p, 0);
    }
    ssize_t r;
    int reads = 0;
    do
        r = read_some(p, fd, tmp, sizeof tmp);
    while (r > 0 && ++reads < 64);
    if (r > 0)
        r = 0;
    pthread_mutex_unlock(&p->rx_mu);
    if (r < 0) {
        pthread_mutex_lock(&p->st_mu);
        p->stats.read_errors++;
        pthread_mutex_unlock(&p->st_mu);
        lf_port_note_error(p, (int)r);
    }
    lf_port_release(p);
    return (int)r;
}

ssize_t fap_port_transact(fap_port *p, const void *req, size_t n, void *reply, size_t cap,
                          int64_t deadline_ns)
{
    if (!p || (!req && n) || n > SSIZE_MAX || (!reply && cap))
        return -EINVAL;
    int err = fap_port_discard_input(p);
    if (err)
        return err;
    if (n) {
        ssize_t w = port_write(p, req, n, 1);
        if (w < 0)
            return w;
    }
    if (!cap)
        return 0;
    if (cap > SSIZE_MAX)
        cap = SSIZE_MAX;
    return port_read(p, reply, cap, deadline_ns, 1);
}
