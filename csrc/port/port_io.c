/* port_io.c - fap_port_read / fap_port_write / fap_port_flush: deadline
 * reads, write-all with EINTR and partial writes, RTS switching, echo
 * read-back, turnaround delay, vanished-device detection. */
#include "port/port_internal.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

#include "common/mono_clock.h"

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
        ssize_t r = p->be->read(p->ctx, fd, p->pend + p->pend_len, 256);
        if (r > 0) {
            p->pend_len += (size_t)r;
            continue;
        }
        if (r == 0) {
            err = -EIO;   /* hung up */
            break;
        }
        if (errno == EINTR)
            continue;
        if (errno != EAGAIN && errno != EWOULDBLOCK)
            err = -errno;
        break;
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
        ssize_t r = p->be->read(p->ctx, fd, tmp, want);
        if (r > 0) {
            if (memcmp(tmp, es->sent + es->got, (size_t)r) != 0)
                es->mismatch = 1;
            es->got += (size_t)r;
            continue;
        }
        if (r == 0)
            return -EIO;   /* hung up */
        if (errno == EINTR)
            continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK)
            return 0;
        return -errno;
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
        int64_t now = lf_now_ns();
        if (now >= deadline)
            return es->mismatch ? FAP_PORT_ECOLLISION : -ETIMEDOUT;
        struct pollfd pf = {.fd = fd, .events = POLLIN};
        int r = p->be->poll(p->ctx, &pf, 1, lf_poll_timeout_ms(deadline, now));
        if (r < 0 && errno != EINTR)
            return -errno;
        if (r > 0 && (pf.revents & POLLNVAL))
            return -EBADF;
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
        int64_t now = lf_now_ns();
        if (now >= deadline)
            return -ETIMEDOUT;
        struct pollfd pf = {.fd = fd, .events = (short)(POLLOUT | (es ? POLLIN : 0))};
        int r = p->be->poll(p->ctx, &pf, 1, lf_poll_timeout_ms(deadline, now));
        if (r < 0) {
            if (errno == EINTR)
                continue;
            return -errno;
        }
        if (r == 0)
            continue;
        if (pf.revents & POLLNVAL)
            return -EBADF;
        if (es && (pf.revents & POLLIN)) {
            int err = echo_take(p, fd, es);
            if (err)
                return err;
        }
        if ((pf.revents & (POLLHUP | POLLERR)) && !(pf.revents & (POLLOUT | POLLIN)))
            return -EIO;
    }
    return 0;
}

static int drain(fap_port *p, int fd)
{
    while (p->be->tcdrain(p->ctx, fd) < 0) {
        if (errno != EINTR)
            return -errno;
    }
    return 0;
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
    /* tcdrain() on a USB adapter returns before its FIFO is on the wire:
     * allow the frame's own wire time on top. */
    return lf_now_ns() + (int64_t)n * ct + wait;
}

ssize_t fap_port_write(fap_port *p, const void *buf, size_t n)
{
    if (!p || (!buf && n) || n > SSIZE_MAX)
        return -EINVAL;
    if (n == 0)
        return 0;
    pthread_mutex_lock(&p->tx_mu);
    int fd;
    fap_rs485_mode mode;
    int err = lf_port_acquire(p, &fd, &mode);
    if (err) {
        pthread_mutex_unlock(&p->tx_mu);
        return err;
    }
    wait_turnaround(p);

    echo_state es = {.sent = buf, .n = n};
    int echo = p->opt.echo_suppression;
    size_t written = 0;
    if (echo) {
        pthread_mutex_lock(&p->rx_mu);
        err = pend_fill(p, fd);
        if (err)
            goto out;
    }
    if (mode == FAP_RS485_SOFT_RTS) {
        err = lf_port_rts(p, fd, 1);
        if (err)
            goto out;   /* nothing sent */
        delay_us(p, p->opt.delay_before_send_us);
    }
    err = write_all(p, fd, buf, n, &written, echo ? &es : NULL);
    if (!err)
        err = drain(p, fd);   /* the last stop bit has left the UART */
    if (mode == FAP_RS485_SOFT_RTS) {
        if (!err)
            delay_us(p, p->opt.delay_after_send_us);
        int rerr = lf_port_rts(p, fd, 0);   /* release even after an error */
        if (!err)
            err = rerr;
    }
    if (!err && echo)
        err = echo_finish(p, fd, &es, echo_deadline(p, n));
out:
    if (echo)
        pthread_mutex_unlock(&p->rx_mu);
    if (err < 0 && err > -4096 && lf_port_errno_vanished(-err))
        lf_port_mark_gone(p, err);
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

/* ---- read -------------------------------------------------------------- */

ssize_t fap_port_read(fap_port *p, void *buf, size_t n, int64_t deadline_ns)
{
    if (!p || (!buf && n))
        return -EINVAL;
    if (n > SSIZE_MAX)
        n = SSIZE_MAX;
    int fd;
    int err = lf_port_acquire(p, &fd, NULL);
    if (err)
        return err;
    ssize_t result = 0;
    short hup = 0;
    int parked = 0;
    for (;;) {
        if (n == 0)
            break;
        /* rx_mu only around read(): a write reading back its echo holds it,
         * so a concurrent reader never sees our own bytes. */
        pthread_mutex_lock(&p->rx_mu);
        ssize_t r;
        int e = 0;
        if (p->pend_len) {
            r = (ssize_t)pend_take(p, buf, n);
            parked = 1;   /* received earlier: last_rx_ns already set */
        } else {
            r = p->be->read(p->ctx, fd, buf, n);
            e = errno;
        }
        pthread_mutex_unlock(&p->rx_mu);
        if (r > 0) {
            result = r;
            break;
        }
        if (r == 0) {   /* a hung-up tty reads as end of file */
            result = -EIO;
            break;
        }
        if (e == EINTR)
            continue;
        if (e != EAGAIN && e != EWOULDBLOCK) {
            result = -e;
            break;
        }
        if (hup) {   /* poll said hang-up and there is nothing to read */
            result = -EIO;
            break;
        }
        int64_t now = lf_now_ns();
        if (deadline_ns == 0 || now >= deadline_ns)
            break;   /* result 0: deadline */
        struct pollfd pf = {.fd = fd, .events = POLLIN};
        int pr = p->be->poll(p->ctx, &pf, 1, lf_poll_timeout_ms(deadline_ns, now));
        if (pr < 0) {
            if (errno == EINTR)
                continue;
            result = -errno;
            break;
        }
        if (pr > 0 && (pf.revents & POLLNVAL)) {
            result = -EBADF;
            break;
        }
        if (pr > 0 && !(pf.revents & POLLIN))
            hup = pf.revents & (POLLHUP | POLLERR);
    }
    pthread_mutex_lock(&p->st_mu);
    if (result > 0) {
        p->stats.rx_bytes += (uint64_t)result;
        if (!parked)
            p->last_rx_ns = lf_now_ns();
    } else if (result < 0) {
        p->stats.read_errors++;
    }
    pthread_mutex_unlock(&p->st_mu);
    if (result < 0 && lf_port_errno_vanished((int)-result))
        lf_port_mark_gone(p, (int)result);
    lf_port_release(p);
    return result;
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
        if (p->be->tcflush(p->ctx, fd, TCIOFLUSH) < 0) {
            err = -errno;
            if (lf_port_errno_vanished(-err))
                lf_port_mark_gone(p, err);
        }
        lf_port_release(p);
    }
    pthread_mutex_unlock(&p->rx_mu);
    pthread_mutex_unlock(&p->tx_mu);
    return err;
}
