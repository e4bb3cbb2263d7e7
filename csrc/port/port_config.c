/* port_config.c - bringing a line up and down: open, lock, raw 8N1 at the
 * baud, RS-485 direction mode (kernel / soft RTS / GPIO / none). Only line
 * operations, through p->be (port_backend.h): termios and the tty ioctls
 * are the device transport's (port_device.c). */
#include "port/port_internal.h"

#include <string.h>

static uint32_t us_to_ms_up(unsigned us)
{
    return (uint32_t)(((uint64_t)us + 999u) / 1000u);   /* no wrap near UINT_MAX */
}

/* The device's own RS-485 config (device tree, an earlier program): 0, or
 * the transport's negative errno (-ENOTTY: the line has none). */
static int kernel_rs485_get(const fap_port *p, int fd, struct serial_rs485 *r)
{
    memset(r, 0, sizeof *r);
    return p->be->rs485_get ? p->be->rs485_get(p->ctx, fd, r) : -ENOTTY;
}

/* Set r, then read back what the driver kept (it clamps delays, drops
 * flags it lacks) into c->rs485_active. c->rs485_saved is restored at close. */
static int kernel_rs485_set(const fap_port *p, int fd, lf_port_conn *c,
                            const struct serial_rs485 *saved, struct serial_rs485 *r)
{
    int err = p->be->rs485_set ? p->be->rs485_set(p->ctx, fd, r) : -ENOTTY;
    if (err)
        return err;
    c->rs485_saved = *saved;
    c->rs485_restore = 1;
    struct serial_rs485 got;
    if (kernel_rs485_get(p, fd, &got) == 0)
        *r = got;
    c->rs485_active = *r;
    return 0;
}

/* The polarity the device's config describes: the kernel's flags are the
 * pin level while sending (RTS_ON_SEND) or after it (RTS_AFTER_SEND);
 * neither or both means RTS_ON_SEND (the kernel's own choice). */
static int rs485_active_high(const struct serial_rs485 *r)
{
    return !((r->flags & SER_RS485_RTS_AFTER_SEND) && !(r->flags & SER_RS485_RTS_ON_SEND));
}

/* Kernel RS-485: start from the device's config, so what the user did not
 * give (FAP_PORT_KEEP) stays as the board has it; what the user gave wins. */
static int kernel_rs485_enable(const fap_port *p, int fd, lf_port_conn *c)
{
    struct serial_rs485 saved, want;
    int err = kernel_rs485_get(p, fd, &saved);
    if (err)
        return err;
    want = saved;
    want.flags |= SER_RS485_ENABLED;
    if (p->opt.rts_active_high != FAP_PORT_KEEP) {
        want.flags &= ~(uint32_t)(SER_RS485_RTS_ON_SEND | SER_RS485_RTS_AFTER_SEND);
        want.flags |= p->opt.rts_active_high ? SER_RS485_RTS_ON_SEND : SER_RS485_RTS_AFTER_SEND;
    }
    if (p->opt.rx_during_tx != FAP_PORT_KEEP) {
        want.flags &= ~(uint32_t)SER_RS485_RX_DURING_TX;
        if (p->opt.rx_during_tx)
            want.flags |= SER_RS485_RX_DURING_TX;
    }
    if (p->opt.delay_before_send_us != FAP_PORT_KEEP_DELAY)
        want.delay_rts_before_send = us_to_ms_up(p->opt.delay_before_send_us);
    if (p->opt.delay_after_send_us != FAP_PORT_KEEP_DELAY)
        want.delay_rts_after_send = us_to_ms_up(p->opt.delay_after_send_us);
    c->rts_active_high = rs485_active_high(&want);
    /* The open asserted RTS, and a driver switching RS-485 on leaves the pin
     * as it is until its first transmission: put it at the receive level
     * while RTS writes still count (best effort: the driver owns it next). */
    if (!(saved.flags & SER_RS485_ENABLED))
        (void)lf_port_rts(p, fd, c, 0);
    err = kernel_rs485_set(p, fd, c, &saved, &want);
    if (err == 0) {
        c->rts_active_high = rs485_active_high(&want);
        c->delay_before_us = want.delay_rts_before_send * 1000u;
        c->delay_after_us = want.delay_rts_after_send * 1000u;
    }
    return err;
}

/* Soft RTS. A driver in RS-485 mode ignores RTS writes and drives the pin
 * itself, so kernel RS-485 goes off while we own the port (restored at
 * close). Polarity and delays not given come from the device's config
 * (it describes the transceiver); a device without one: high, 0, 0. */
static int soft_rts_enable(const fap_port *p, int fd, lf_port_conn *c)
{
    struct serial_rs485 cur;
    int err = kernel_rs485_get(p, fd, &cur);
    if (err && fap_port_error_is_gone(err))
        return err;
    int have = err == 0;
    if (have && (cur.flags & SER_RS485_ENABLED)) {
        struct serial_rs485 off = cur;
        off.flags &= ~(uint32_t)SER_RS485_ENABLED;
        err = kernel_rs485_set(p, fd, c, &cur, &off);
        if (err)
            return err;
    }
    c->rts_active_high = p->opt.rts_active_high != FAP_PORT_KEEP ? p->opt.rts_active_high
                         : have ? rs485_active_high(&cur) : 1;
    c->delay_before_us = p->opt.delay_before_send_us != FAP_PORT_KEEP_DELAY
                             ? p->opt.delay_before_send_us
                         : have ? cur.delay_rts_before_send * 1000u : 0;
    c->delay_after_us = p->opt.delay_after_send_us != FAP_PORT_KEEP_DELAY
                            ? p->opt.delay_after_send_us
                        : have ? cur.delay_rts_after_send * 1000u : 0;
    /* Receive level now: the open itself asserted RTS. This also proves
     * the device has an RTS line. */
    return lf_port_rts(p, fd, c, 0);
}

/* GPIO DE/RE: the line requested as an output already at the receive
 * level; polarity and delays as soft RTS takes them (no device config to
 * fall back on: high, 0, 0). */
static int gpio_enable(const fap_port *p, lf_port_conn *c)
{
    if (!p->be->gpio_open || !p->be->gpio_set)
        return -EOPNOTSUPP;
    c->rts_active_high = p->opt.rts_active_high != FAP_PORT_KEEP ? p->opt.rts_active_high : 1;
    c->delay_before_us = p->opt.delay_before_send_us != FAP_PORT_KEEP_DELAY
                             ? p->opt.delay_before_send_us : 0;
    c->delay_after_us = p->opt.delay_after_send_us != FAP_PORT_KEEP_DELAY
                            ? p->opt.delay_after_send_us : 0;
    int fd = p->be->gpio_open(p->ctx, p->opt.gpio_chip, p->opt.gpio_line, !c->rts_active_high);
    if (fd < 0)
        return fd;
    c->gpio_fd = fd;
    return 0;
}

int lf_port_rts(const fap_port *p, int fd, const lf_port_conn *c, int sending)
{
    if (c->gpio_fd >= 0)   /* the DE line is a GPIO: its level is the pin's */
        return p->be->gpio_set(p->ctx, c->gpio_fd, sending ? c->rts_active_high
                                                           : !c->rts_active_high);
    if (!p->be->rts)
        return -ENOTTY;   /* a line without an RTS pin */
    /* The pin level: high while sending for an active-high transceiver. */
    return p->be->rts(p->ctx, fd, sending ? c->rts_active_high : !c->rts_active_high);
}

static int setup_direction(const fap_port *p, int fd, lf_port_conn *c)
{
    int err;
    switch (p->opt.rs485_mode) {
    case FAP_RS485_NONE:
        c->mode = FAP_RS485_NONE;
        return 0;
    case FAP_RS485_KERNEL:
        err = kernel_rs485_enable(p, fd, c);
        if (err == 0)
            c->mode = FAP_RS485_KERNEL;
        return err;
    case FAP_RS485_SOFT_RTS:
        err = soft_rts_enable(p, fd, c);
        if (err == 0)
            c->mode = FAP_RS485_SOFT_RTS;
        return err;
    case FAP_RS485_GPIO:
        err = gpio_enable(p, c);
        if (err == 0)
            c->mode = FAP_RS485_GPIO;
        return err;
    case FAP_RS485_AUTO:
        err = kernel_rs485_enable(p, fd, c);
        if (err == 0) {
            c->mode = FAP_RS485_KERNEL;
            return 0;
        }
        if (fap_port_error_is_gone(err))
            return err;   /* a dying device is not "no RS-485 support" */
        c->mode = FAP_RS485_NONE;
        c->auto_errno = -err;
        return 0;
    }
    return -EINVAL;
}

int lf_port_conn_open(const fap_port *p, lf_port_conn *c)
{
    memset(c, 0, sizeof *c);
    c->fd = -1;
    c->gpio_fd = -1;
    c->latency_saved = -1;
    int fd = p->be->open(p->ctx, p->path);
    if (fd < 0)
        return fd;
    c->fd = fd;
    int err = 0;
    /* The lock binds everyone; a non-exclusive opener takes a shared one:
     * it shares with its kind, never with an exclusive owner. */
    if (p->be->lock) {
        err = p->be->lock(p->ctx, fd, p->opt.exclusive);
        if (err)
            goto fail;
        c->excl_set = p->opt.exclusive;
    }
    /* Direction first: the open asserted RTS, which on an active-low
     * transceiver is the transmit level. */
    err = setup_direction(p, fd, c);
    if (err)
        goto fail;
    /* Soft RTS: the close must not move RTS, and puts the line back */
    c->tio_restore = c->mode == FAP_RS485_SOFT_RTS;
    err = p->be->set_line(p->ctx, fd, p->opt.baud, c->tio_restore);
    if (err)
        goto fail;
    lf_port_latency_low(p, c);
    /* Bytes that piled up before we attached are not for us. */
    err = p->be->flush(p->ctx, fd, LF_PORT_FLUSH_BOTH);
    if (err)
        goto fail;
    return 0;
fail:
    lf_port_conn_close(p, c);
    return err;
}

void lf_port_conn_close(const fap_port *p, lf_port_conn *c)
{
    if (c->gpio_fd >= 0) {   /* the DE line to the receive level, then free it */
        (void)lf_port_rts(p, c->fd, c, 0);
        (void)p->be->close(p->ctx, c->gpio_fd);
        c->gpio_fd = -1;
    }
    lf_port_latency_restore(c);
    if (c->fd < 0)
        return;
    /* Best effort: on a vanished device these fail, and that is fine. */
    if (c->tio_restore) {
        /* Soft RTS: the pin to the receive level, then the line as it was,
         * without moving RTS (the transport's restore_line). */
        (void)lf_port_rts(p, c->fd, c, 0);
        if (p->be->restore_line)
            p->be->restore_line(p->ctx, c->fd, p->opt.baud);
    }
    if (c->rs485_restore && p->be->rs485_set)
        (void)p->be->rs485_set(p->ctx, c->fd, &c->rs485_saved);
    if (c->excl_set && p->be->unlock)
        p->be->unlock(p->ctx, c->fd);
    (void)p->be->close(p->ctx, c->fd);   /* also drops the lock */
    c->fd = -1;
    c->rs485_restore = 0;
    c->tio_restore = 0;
    c->excl_set = 0;
}
