/* port_check.c - fap_port_check_direction: when does the port release the
 * direction line, against the last byte the transceiver echoed? A second
 * thread reads the echo of each round's pattern and notes when the last
 * byte was read; the caller's thread writes (soft RTS / GPIO: returns after
 * the release) and notes when the write returned. */
#include "port/port_internal.h"

#include <stdlib.h>
#include <string.h>

typedef struct echo_reader {
    fap_port *p;
    const uint8_t *sent;
    size_t n, got;
    int64_t deadline, last_ns;
    uint64_t differ;
} echo_reader;

static void *read_echo(void *arg)
{
    echo_reader *r = arg;
    uint8_t buf[256];
    while (r->got < r->n) {
        size_t want = r->n - r->got < sizeof buf ? r->n - r->got : sizeof buf;
        ssize_t k = fap_port_read(r->p, buf, want, r->deadline);
        if (k <= 0)
            break;   /* the deadline, or the port failed: the round has what it got */
        r->last_ns = fap_port_now_ns();
        for (ssize_t i = 0; i < k; i++)
            r->differ += buf[i] != r->sent[r->got + (size_t)i];
        r->got += (size_t)k;
    }
    return NULL;
}

int fap_port_check_direction(fap_port *p, const void *pattern, size_t n, unsigned rounds,
                             unsigned timeout_ms, fap_port_check *out)
{
    if (!p || !pattern || !n || !out || rounds > FAP_PORT_CHECK_MAX_ROUNDS ||
        p->opt.echo_suppression)
        return -EINVAL;
    memset(out, 0, sizeof *out);
    for (unsigned i = 0; i < rounds; i++) {
        int err = fap_port_discard_input(p);   /* not our echo */
        if (err)
            return err;
        echo_reader r = {.p = p, .sent = pattern, .n = n,
                         .deadline = fap_port_now_ns() + (int64_t)timeout_ms * 1000000};
        pthread_t t;
        err = pthread_create(&t, NULL, read_echo, &r);
        if (err)
            return -err;
        ssize_t w = fap_port_write(p, pattern, n);
        int64_t release = fap_port_now_ns();
        pthread_join(t, NULL);
        if (w < 0)
            return (int)w;
        out->rounds++;
        out->collisions += r.differ;
        if (r.got == n)
            out->margin_ns[out->echoed++] = release - r.last_ns;
    }
    return 0;
}
