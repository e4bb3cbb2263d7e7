/* vbus_wire.c - fault injection, pacing and collisions of the virtual bus.
 * Sans-I/O: bytes and a clock in, sink callbacks out (see vbus_wire.h). */
#include "vbus/vbus_wire.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#define LF_WIRE_F_DROPPED  0x01u   /* takes wire time, reaches nobody */
#define LF_WIRE_F_COLLIDED 0x02u   /* overlapped another sender: delivered inverted */

static const char *const reason_names[LF_WIRE_REASON_COUNT] = {
    "silence", "drop_next", "drop_rate", "corrupt_next", "bit_error",
};

const char *lf_wire_reason_name(lf_wire_reason r)
{
    return (unsigned)r < LF_WIRE_REASON_COUNT ? reason_names[r] : "?";
}

/* splitmix64: tiny, fast, and good enough to decide faults reproducibly. */
static uint64_t rng_next(uint64_t *s)
{
    uint64_t z = (*s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static double rng_unit(uint64_t *s)
{
    return (double)(rng_next(s) >> 11) * 0x1.0p-53;
}

int lf_wire_init(lf_wire *w, unsigned n_ports, unsigned baud, int echo, uint64_t seed,
                 const lf_wire_sink *sink)
{
    if (!w || !sink || n_ports < 2 || n_ports > LF_WIRE_MAX_PORTS)
        return -EINVAL;
    memset(w, 0, sizeof *w);
    w->n_ports = n_ports;
    w->char_ns = lf_char_time_ns(baud);
    if (baud && w->char_ns < 1)
        return -EINVAL;
    w->echo = echo ? 1 : 0;
    w->sink = *sink;
    for (unsigned i = 0; i < n_ports; i++) {
        lf_wire_port *pt = &w->port[i];
        pt->connected = 1;
        /* Each port draws from its own stream, so a port's k-th byte meets
         * the same fate whatever the other ports do. */
        pt->rng = seed ^ (0xD1B54A32D192ED03ull * (i + 1));
        if (w->char_ns) {
            pt->fifo = calloc(LF_WIRE_PENDING_CAP, sizeof *pt->fifo);
            if (!pt->fifo) {
                lf_wire_free(w);
                return -ENOMEM;
            }
        }
    }
    return 0;
}

void lf_wire_free(lf_wire *w)
{
    if (!w)
        return;
    for (unsigned i = 0; i < LF_WIRE_MAX_PORTS; i++) {
        free(w->port[i].fifo);
        w->port[i].fifo = NULL;
        w->port[i].count = 0;
    }
}

size_t lf_wire_space(const lf_wire *w, unsigned p)
{
    if (!w->char_ns)
        return SIZE_MAX;
    return LF_WIRE_PENDING_CAP - w->port[p].count;
}

uint64_t lf_wire_receivers(const lf_wire *w, unsigned sender, lf_ns now)
{
    uint64_t to = 0;
    for (unsigned q = 0; q < w->n_ports; q++) {
        const lf_wire_port *pt = &w->port[q];
        if (!pt->connected || now < pt->silent_until)
            continue;
        if (q == sender && !w->echo)
            continue;
        to |= 1ull << q;
    }
    return to;
}

static void flip_random_bit(lf_wire_port *pt, uint8_t *v)
{
    *v ^= (uint8_t)(1u << (rng_next(&pt->rng) & 7u));
}

/* Decide the fate of one byte sent by pt. Returns 0 to drop it, 1 to keep
 * it (*v possibly corrupted); counts[reason] records what happened. The
 * draws depend only on this port's settings and history: reproducible. */
static int fault_byte(lf_wire_port *pt, uint8_t *v, size_t counts[LF_WIRE_REASON_COUNT])
{
    if (pt->drop_next) {
        pt->drop_next--;
        counts[LF_WIRE_DROP_NEXT]++;
        return 0;
    }
    if (pt->corrupt_next) {
        pt->corrupt_next--;
        flip_random_bit(pt, v);
        counts[LF_WIRE_CORRUPT_NEXT]++;
        return 1;
    }
    if (pt->drop_rate > 0.0 && rng_unit(&pt->rng) < pt->drop_rate) {
        counts[LF_WIRE_DROP_RATE]++;
        return 0;
    }
    if (pt->bit_error_rate > 0.0 && rng_unit(&pt->rng) < pt->bit_error_rate) {
        flip_random_bit(pt, v);
        counts[LF_WIRE_BIT_ERROR]++;
    }
    return 1;
}

static void report_faults(lf_wire *w, unsigned p, const size_t counts[LF_WIRE_REASON_COUNT],
                          lf_ns t)
{
    for (unsigned r = 0; r < LF_WIRE_REASON_COUNT; r++) {
        if (!counts[r])
            continue;
        if (r == LF_WIRE_CORRUPT_NEXT || r == LF_WIRE_BIT_ERROR)
            w->stats.bit_errors += counts[r];
        else
            w->stats.dropped += counts[r];
        if (w->sink.fault)
            w->sink.fault(w->sink.ctx, p, (lf_wire_reason)r, counts[r], t);
    }
}

static lf_wire_byte *fifo_at(lf_wire_port *pt, size_t k)
{
    return &pt->fifo[(pt->head + k) % LF_WIRE_PENDING_CAP];
}

/* Paced: mark the bytes where p's new span [s, e) (n bytes from fifo index
 * base) overlaps what other senders have on the wire; count each pair of
 * overlapping bursts once. */
static void detect_collisions(lf_wire *w, unsigned p, size_t base, size_t n, lf_ns s, lf_ns e)
{
    const lf_ns T = w->char_ns;
    lf_wire_port *pp = &w->port[p];
    for (unsigned q = 0; q < w->n_ports; q++) {
        lf_wire_port *pq = &w->port[q];
        if (q == p || !pq->count)
            continue;
        lf_ns first_overlap = LF_NEVER;
        /* q's FIFO is in wire order: walk back from the newest byte until
         * bytes end before our span starts. */
        for (size_t j = pq->count; j-- > 0;) {
            lf_wire_byte *b = fifo_at(pq, j);
            lf_ns bend = b->begin + T;
            if (bend <= s)
                break;
            if (b->begin >= e)
                continue;
            b->flags |= LF_WIRE_F_COLLIDED;
            size_t k0 = b->begin <= s ? 0 : (size_t)((b->begin - s) / T);
            size_t k1 = (size_t)((bend - s + T - 1) / T);   /* exclusive */
            if (k1 > n)
                k1 = n;
            for (size_t k = k0; k < k1; k++)
                fifo_at(pp, base + k)->flags |= LF_WIRE_F_COLLIDED;
            if (b->begin < first_overlap)
                first_overlap = b->begin;
        }
        if (first_overlap == LF_NEVER)
            continue;
        uint64_t qbit = 1ull << q;
        if (pp->collided_with & qbit)
            continue;
        pp->collided_with |= qbit;
        pq->collided_with |= 1ull << p;
        w->stats.collisions++;
        if (w->sink.collision)
            w->sink.collision(w->sink.ctx, p, q, first_overlap > s ? first_overlap : s);
    }
}

void lf_wire_send(lf_wire *w, unsigned p, uint8_t *data, size_t n, lf_ns now)
{
    lf_wire_port *pt = &w->port[p];
    size_t counts[LF_WIRE_REASON_COUNT] = { 0 };
    if (!n)
        return;
    w->stats.bytes_in += n;
    if (now < pt->silent_until) {
        /* a silenced node's transmitter never reaches the wire */
        counts[LF_WIRE_SILENCE] = n;
        report_faults(w, p, counts, now);
        return;
    }
    if (!w->char_ns) {
        size_t kept = 0;
        for (size_t i = 0; i < n; i++) {
            uint8_t v = data[i];
            if (fault_byte(pt, &v, counts))
                data[kept++] = v;
        }
        report_faults(w, p, counts, now);
        /* delivered even to nobody: the capture still sees the wire */
        if (kept)
            w->sink.deliver(w->sink.ctx, p, lf_wire_receivers(w, p, now), data, kept, now);
        return;
    }

    const lf_ns T = w->char_ns;
    if (n > LF_WIRE_PENDING_CAP - pt->count)
        n = LF_WIRE_PENDING_CAP - pt->count;   /* caller broke the contract; stay safe */
    lf_ns s = now > pt->wire_end ? now : pt->wire_end;
    if (s > pt->wire_end) {
        /* a new burst after silence on this sender's side */
        pt->collided_with = 0;
        for (unsigned q = 0; q < w->n_ports; q++)
            w->port[q].collided_with &= ~(1ull << p);
    }
    size_t base = pt->count;
    for (size_t i = 0; i < n; i++) {
        lf_wire_byte *b = fifo_at(pt, pt->count++);
        b->value = data[i];
        b->begin = s + (lf_ns)i * T;
        /* a dropped byte still occupied the wire; receivers just lost it */
        b->flags = fault_byte(pt, &b->value, counts) ? 0 : LF_WIRE_F_DROPPED;
    }
    lf_ns e = s + (lf_ns)n * T;
    pt->wire_end = e;
    report_faults(w, p, counts, s);
    detect_collisions(w, p, base, n, s, e);
}

void lf_wire_advance(lf_wire *w, lf_ns now)
{
    const lf_ns T = w->char_ns;
    if (!T)
        return;
    for (;;) {
        /* the due sender whose head started first goes next: wire order */
        int best = -1;
        lf_ns best_begin = LF_NEVER, second = LF_NEVER;
        for (unsigned q = 0; q < w->n_ports; q++) {
            lf_wire_port *pq = &w->port[q];
            if (!pq->count)
                continue;
            lf_ns b = fifo_at(pq, 0)->begin;
            if (b + T > now)
                continue;
            if (b < best_begin) {
                second = best_begin;
                best_begin = b;
                best = (int)q;
            } else if (b < second) {
                second = b;
            }
        }
        if (best < 0)
            return;
        lf_wire_port *pt = &w->port[best];
        uint8_t run[LF_WIRE_RUN_MAX];
        size_t m = 0;
        lf_ns t0 = 0;
        while (pt->count && m < LF_WIRE_RUN_MAX) {
            lf_wire_byte *b = fifo_at(pt, 0);
            if (b->begin + T > now || (m && b->begin > second))
                break;
            pt->head = (pt->head + 1) % LF_WIRE_PENDING_CAP;
            pt->count--;
            if (b->flags & LF_WIRE_F_DROPPED) {
                if (m)
                    break;
                continue;
            }
            if (!m)
                t0 = b->begin;
            uint64_t late = (uint64_t)(now - (b->begin + T));   /* >= 0: it was due */
            w->stats.paced_bytes++;
            w->stats.late_sum_ns += late;
            if (late > w->stats.late_max_ns)
                w->stats.late_max_ns = late;
            /* collision rule: every overlapped byte arrives bit-inverted */
            run[m++] = (b->flags & LF_WIRE_F_COLLIDED) ? (uint8_t)~b->value : b->value;
        }
        if (m)
            w->sink.deliver(w->sink.ctx, (unsigned)best,
                            lf_wire_receivers(w, (unsigned)best, now), run, m, t0);
    }
}

lf_ns lf_wire_next_due(const lf_wire *w)
{
    lf_ns due = LF_NEVER;
    if (!w->char_ns)
        return due;
    for (unsigned q = 0; q < w->n_ports; q++) {
        const lf_wire_port *pq = &w->port[q];
        if (!pq->count)
            continue;
        lf_ns end = pq->fifo[pq->head].begin + w->char_ns;
        if (end < due)
            due = end;
    }
    return due;
}

void lf_wire_set_rates(lf_wire *w, unsigned p, double bit_error_rate, double drop_rate)
{
    w->port[p].bit_error_rate = bit_error_rate;
    w->port[p].drop_rate = drop_rate;
}

void lf_wire_drop_next(lf_wire *w, unsigned p, unsigned n)
{
    w->port[p].drop_next = n;
}

void lf_wire_corrupt_next(lf_wire *w, unsigned p, unsigned n)
{
    w->port[p].corrupt_next = n;
}

void lf_wire_silence(lf_wire *w, unsigned p, lf_ns until)
{
    w->port[p].silent_until = until;
}

void lf_wire_set_connected(lf_wire *w, unsigned p, int connected)
{
    w->port[p].connected = connected ? 1 : 0;
}
