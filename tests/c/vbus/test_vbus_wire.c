/* test_vbus_wire.c - the sans-I/O wire model with a fake clock: exact
 * pacing, the collision rule, faults and their reproducibility. */
#include <errno.h>
#include <string.h>

#include "unit.h"
#include "vbus/vbus_wire.h"

#define T9600 1041666   /* ns per byte at 9600 baud (10 bits) */

typedef struct rec {
    unsigned sender;
    uint64_t to;
    uint8_t data[512];
    size_t n;
    lf_ns t;
} rec;

typedef struct log_sink {
    rec recs[64];
    int n_recs;
    unsigned coll_a[16], coll_b[16];
    lf_ns coll_t[16];
    int n_coll;
    size_t faults[LF_WIRE_REASON_COUNT];
} log_sink;

static void on_deliver(void *ctx, unsigned sender, uint64_t to, const uint8_t *d, size_t n,
                       lf_ns t)
{
    log_sink *l = ctx;
    if (l->n_recs >= 64)
        return;
    rec *r = &l->recs[l->n_recs++];
    r->sender = sender;
    r->to = to;
    r->n = n < sizeof r->data ? n : sizeof r->data;
    memcpy(r->data, d, r->n);
    r->t = t;
}

static void on_collision(void *ctx, unsigned a, unsigned b, lf_ns t)
{
    log_sink *l = ctx;
    if (l->n_coll < 16) {
        l->coll_a[l->n_coll] = a;
        l->coll_b[l->n_coll] = b;
        l->coll_t[l->n_coll++] = t;
    }
}

static void on_fault(void *ctx, unsigned port, lf_wire_reason r, size_t n, lf_ns t)
{
    (void)port;
    (void)t;
    ((log_sink *)ctx)->faults[r] += n;
}

static int wire_open(lf_wire *w, log_sink *l, unsigned ports, unsigned baud, int echo,
                     uint64_t seed)
{
    memset(l, 0, sizeof *l);
    lf_wire_sink s = { .ctx = l, .deliver = on_deliver, .collision = on_collision,
                       .fault = on_fault };
    return lf_wire_init(w, ports, baud, echo, seed, &s);
}

static lf_wire w;   /* large: keep it off the stack */

static void test_init_rejects_bad_arguments(void)
{
    log_sink l;
    CHECK_EQ(wire_open(&w, &l, 1, 0, 0, 0), -EINVAL);
    CHECK_EQ(wire_open(&w, &l, LF_WIRE_MAX_PORTS + 1, 0, 0, 0), -EINVAL);
    CHECK_EQ(wire_open(&w, &l, 2, 0, 0, 0), 0);
    lf_wire_free(&w);
}

static void test_unpaced_delivers_at_once_to_the_others(void)
{
    log_sink l;
    int opened = wire_open(&w, &l, 3, 0, 0, 0);   /* not inside REQUIRE: it evaluates twice */
    REQUIRE(opened == 0);
    CHECK_EQ(lf_wire_space(&w, 0), SIZE_MAX);
    uint8_t d[] = "abc";
    lf_wire_send(&w, 1, d, 3, 500);
    REQUIRE(l.n_recs == 1);
    CHECK_EQ(l.recs[0].sender, 1);
    CHECK_EQ(l.recs[0].to, 0x5);   /* ports 0 and 2, not the sender */
    CHECK_EQ(l.recs[0].t, 500);
    CHECK_MEM(l.recs[0].data, "abc", 3);
    CHECK_EQ(lf_wire_next_due(&w), LF_NEVER);
    lf_wire_set_connected(&w, 2, 0);
    CHECK_EQ(lf_wire_receivers(&w, 1, 0), 0x1);
    lf_wire_free(&w);

    opened = wire_open(&w, &l, 3, 0, 1, 0);   /* not inside REQUIRE: it evaluates twice */
    REQUIRE(opened == 0);   /* echo */
    CHECK_EQ(lf_wire_receivers(&w, 1, 0), 0x7);
    lf_wire_free(&w);
}

static void test_paced_bytes_arrive_when_their_wire_time_ends(void)
{
    log_sink l;
    int opened = wire_open(&w, &l, 2, 9600, 0, 0);   /* not inside REQUIRE: it evaluates twice */
    REQUIRE(opened == 0);
    CHECK_EQ(w.char_ns, T9600);
    uint8_t d[3] = { 1, 2, 3 };
    lf_wire_send(&w, 0, d, 3, 1000);
    CHECK_EQ(lf_wire_space(&w, 0), LF_WIRE_PENDING_CAP - 3);
    CHECK_EQ(lf_wire_next_due(&w), 1000 + T9600);
    lf_wire_advance(&w, 1000 + T9600 - 1);
    CHECK_EQ(l.n_recs, 0);
    lf_wire_advance(&w, 1000 + T9600);
    REQUIRE(l.n_recs == 1);
    CHECK_EQ(l.recs[0].n, 1);
    CHECK_EQ(l.recs[0].t, 1000);
    CHECK_EQ(lf_wire_next_due(&w), 1000 + 2 * T9600);
    CHECK_EQ(w.stats.late_max_ns, 0);
    lf_wire_advance(&w, 1000 + 3 * T9600);   /* late: both in one run */
    CHECK_EQ(w.stats.paced_bytes, 3);
    CHECK_EQ(w.stats.late_sum_ns, T9600);   /* byte 1 was one char time late */
    CHECK_EQ(w.stats.late_max_ns, T9600);
    REQUIRE(l.n_recs == 2);
    CHECK_EQ(l.recs[1].n, 2);
    CHECK_EQ(l.recs[1].t, 1000 + T9600);
    CHECK_MEM(l.recs[1].data, "\x02\x03", 2);
    CHECK_EQ(lf_wire_next_due(&w), LF_NEVER);

    /* a write while the sender's previous bytes are on the wire queues
     * behind them; a 100-byte frame ends 104.17 ms after it starts */
    uint8_t frame[100] = { 0 };
    lf_ns t0 = 10 * LF_NS_PER_S;
    lf_wire_send(&w, 1, frame, 50, t0);
    lf_wire_send(&w, 1, frame + 50, 50, t0 + 1000);
    lf_wire_advance(&w, t0 + 100 * (lf_ns)T9600 - 1);
    size_t got = 0;
    for (int i = 2; i < l.n_recs; i++)
        got += l.recs[i].n;
    CHECK_EQ(got, 99);
    lf_wire_advance(&w, t0 + 100 * (lf_ns)T9600);
    CHECK_EQ(l.recs[l.n_recs - 1].t, t0 + 99 * (lf_ns)T9600);
    CHECK_EQ(w.stats.collisions, 0);
    lf_wire_free(&w);
}

static void test_space_limits_a_sender(void)
{
    log_sink l;
    int opened = wire_open(&w, &l, 2, 115200, 0, 0);   /* not inside REQUIRE: it evaluates twice */
    REQUIRE(opened == 0);
    static uint8_t big[LF_WIRE_PENDING_CAP + 10];
    lf_wire_send(&w, 0, big, sizeof big, 0);   /* over the contract: clipped */
    CHECK_EQ(lf_wire_space(&w, 0), 0);
    CHECK_EQ(lf_wire_space(&w, 1), LF_WIRE_PENDING_CAP);
    /* 0.1 s at 115200 baud is 1152 char times: that much room again */
    lf_wire_advance(&w, LF_NS_PER_S / 10);
    CHECK_EQ(lf_wire_space(&w, 0), 1152);
    lf_wire_advance(&w, LF_NS_PER_S);
    CHECK_EQ(lf_wire_space(&w, 0), LF_WIRE_PENDING_CAP);
    lf_wire_free(&w);
}

static void test_partial_overlap_inverts_only_overlapping_bytes(void)
{
    log_sink l;
    int opened = wire_open(&w, &l, 3, 9600, 0, 0);   /* not inside REQUIRE: it evaluates twice */
    REQUIRE(opened == 0);
    const lf_ns T = T9600;
    uint8_t a[4] = { 0x10, 0x11, 0x12, 0x13 }, b[2] = { 0x20, 0x21 };
    lf_wire_send(&w, 0, a, 4, 0);             /* [0, 4T) */
    lf_wire_send(&w, 1, b, 2, 3 * T + T / 2); /* [3.5T, 5.5T) */
    CHECK_EQ(w.stats.collisions, 1);
    REQUIRE(l.n_coll == 1);
    CHECK_EQ(l.coll_a[0], 1);
    CHECK_EQ(l.coll_b[0], 0);
    CHECK_EQ(l.coll_t[0], 3 * T + T / 2);
    lf_wire_advance(&w, 10 * T);
    /* wire order: a0..a2 clean, a3 inverted, b0 inverted, b1 clean */
    uint8_t seen[6];
    unsigned from[6];
    size_t k = 0;
    for (int i = 0; i < l.n_recs; i++)
        for (size_t j = 0; j < l.recs[i].n && k < 6; j++) {
            seen[k] = l.recs[i].data[j];
            from[k++] = l.recs[i].sender;
        }
    REQUIRE(k == 6);
    const uint8_t want[6] = { 0x10, 0x11, 0x12, (uint8_t)~0x13, (uint8_t)~0x20, 0x21 };
    CHECK_MEM(seen, want, 6);
    CHECK_EQ(from[3], 0);
    CHECK_EQ(from[4], 1);
    /* every receiver, senders included, hears the collision */
    for (int i = 0; i < l.n_recs; i++)
        CHECK_EQ(l.recs[i].to, 0x7 & ~(1u << l.recs[i].sender));
    lf_wire_free(&w);
}

static void test_collision_counted_once_per_pair_of_bursts(void)
{
    log_sink l;
    int opened = wire_open(&w, &l, 3, 9600, 0, 0);   /* not inside REQUIRE: it evaluates twice */
    REQUIRE(opened == 0);
    const lf_ns T = T9600;
    uint8_t d[10] = { 0 };
    lf_wire_send(&w, 0, d, 10, 0);          /* [0, 10T) */
    lf_wire_send(&w, 1, d, 1, T);           /* collides */
    lf_wire_send(&w, 1, d, 1, T + T / 2);   /* same burst of port 1: queued at 2T */
    CHECK_EQ(w.stats.collisions, 1);
    lf_wire_send(&w, 1, d, 1, 5 * T);       /* port 1 went idle at 3T: a new burst */
    CHECK_EQ(w.stats.collisions, 2);
    lf_wire_send(&w, 2, d, 1, 6 * T);       /* a third port joins: pair (2,0) */
    CHECK_EQ(w.stats.collisions, 3);
    lf_wire_advance(&w, 20 * T);
    CHECK_EQ(lf_wire_next_due(&w), LF_NEVER);
    /* after the wire went quiet, a new frame is clean */
    lf_wire_send(&w, 0, d, 2, 30 * T);
    lf_wire_advance(&w, 40 * T);
    CHECK_EQ(w.stats.collisions, 3);
    CHECK_EQ(l.recs[l.n_recs - 1].data[1], 0);
    lf_wire_free(&w);
}

static void test_dropped_byte_still_holds_the_wire(void)
{
    log_sink l;
    int opened = wire_open(&w, &l, 2, 9600, 0, 0);   /* not inside REQUIRE: it evaluates twice */
    REQUIRE(opened == 0);
    const lf_ns T = T9600;
    lf_wire_drop_next(&w, 0, 1);
    uint8_t d[2] = { 'a', 'b' };
    lf_wire_send(&w, 0, d, 2, 0);
    CHECK_EQ(l.faults[LF_WIRE_DROP_NEXT], 1);
    CHECK_EQ(w.stats.dropped, 1);
    lf_wire_advance(&w, T);
    CHECK_EQ(l.n_recs, 0);
    lf_wire_advance(&w, 2 * T);
    REQUIRE(l.n_recs == 1);
    CHECK_EQ(l.recs[0].t, T);
    CHECK_EQ(l.recs[0].data[0], 'b');
    /* a byte from port 1 during the dropped one collides with it */
    lf_wire_drop_next(&w, 0, 1);
    lf_wire_send(&w, 0, d, 1, 10 * T);
    lf_wire_send(&w, 1, d + 1, 1, 10 * T + 10);
    CHECK_EQ(w.stats.collisions, 1);
    lf_wire_advance(&w, 20 * T);
    CHECK_EQ(l.recs[l.n_recs - 1].data[0], (uint8_t)~'b');
    lf_wire_free(&w);
}

static void test_silence_drops_and_deafens(void)
{
    log_sink l;
    int opened = wire_open(&w, &l, 3, 0, 0, 0);   /* not inside REQUIRE: it evaluates twice */
    REQUIRE(opened == 0);
    lf_wire_silence(&w, 1, 100);
    uint8_t d[4] = "xyz";
    lf_wire_send(&w, 1, d, 3, 50);
    CHECK_EQ(l.n_recs, 0);
    CHECK_EQ(l.faults[LF_WIRE_SILENCE], 3);
    CHECK_EQ(w.stats.dropped, 3);
    CHECK_EQ(w.stats.bytes_in, 3);
    lf_wire_send(&w, 0, d, 3, 60);
    REQUIRE(l.n_recs == 1);
    CHECK_EQ(l.recs[0].to, 0x4);
    lf_wire_send(&w, 0, d, 3, 100);   /* silence over */
    REQUIRE(l.n_recs == 2);
    CHECK_EQ(l.recs[1].to, 0x6);
    lf_wire_free(&w);
}

static void test_corrupt_next_and_drop_next_are_exact(void)
{
    log_sink l;
    int opened = wire_open(&w, &l, 2, 0, 0, 11);   /* not inside REQUIRE: it evaluates twice */
    REQUIRE(opened == 0);
    uint8_t d[8] = { 0, 0, 0, 0, 0, 0, 0, 0 };
    lf_wire_drop_next(&w, 0, 2);
    lf_wire_corrupt_next(&w, 0, 3);
    lf_wire_send(&w, 0, d, 8, 0);
    REQUIRE(l.n_recs == 1);
    CHECK_EQ(l.recs[0].n, 6);
    for (int i = 0; i < 6; i++)
        CHECK_EQ(__builtin_popcount(l.recs[0].data[i]), i < 3 ? 1 : 0);
    CHECK_EQ(w.stats.bit_errors, 3);
    CHECK_EQ(w.stats.dropped, 2);
    CHECK_EQ(l.faults[LF_WIRE_CORRUPT_NEXT], 3);
    lf_wire_free(&w);
}

/* Send 200 zero bytes from port 0 in chunks of `chunk`, with port 1
 * interleaving traffic; return what port 1 received. */
static size_t random_run(uint64_t seed, size_t chunk, uint8_t *out)
{
    log_sink l;
    if (wire_open(&w, &l, 2, 0, 0, seed) != 0)
        return 0;
    lf_wire_set_rates(&w, 0, 0.2, 0.1);
    lf_wire_set_rates(&w, 1, 0.5, 0.5);
    size_t n = 0;
    uint8_t buf[200];
    for (size_t off = 0; off < 200; off += chunk) {
        size_t m = 200 - off < chunk ? 200 - off : chunk;
        memset(buf, 0, m);
        l.n_recs = 0;
        lf_wire_send(&w, 0, buf, m, (lf_ns)off);
        for (int i = 0; i < l.n_recs; i++) {
            memcpy(out + n, l.recs[i].data, l.recs[i].n);
            n += l.recs[i].n;
        }
        uint8_t other[3] = { 1, 2, 3 };
        lf_wire_send(&w, 1, other, chunk % 3 + 1, (lf_ns)off);
    }
    lf_wire_free(&w);
    return n;
}

static void test_random_faults_reproduce_whatever_the_chunking(void)
{
    uint8_t a[200], b[200], c[200];
    size_t na = random_run(77, 200, a);
    size_t nb = random_run(77, 7, b);
    size_t nc = random_run(78, 200, c);
    CHECK(na > 140 && na < 195);   /* ~10 % dropped */
    CHECK_EQ(na, nb);
    CHECK_MEM(a, b, na);
    CHECK(na != nc || memcmp(a, c, na) != 0);
    int flipped = 0;
    for (size_t i = 0; i < na; i++) {
        CHECK(__builtin_popcount(a[i]) <= 1);
        flipped += __builtin_popcount(a[i]);
    }
    CHECK(flipped > 15 && flipped < 70);   /* ~20 % of ~180 */
}

UNIT_MAIN(
    UNIT(test_init_rejects_bad_arguments),
    UNIT(test_unpaced_delivers_at_once_to_the_others),
    UNIT(test_paced_bytes_arrive_when_their_wire_time_ends),
    UNIT(test_space_limits_a_sender),
    UNIT(test_partial_overlap_inverts_only_overlapping_bytes),
    UNIT(test_collision_counted_once_per_pair_of_bursts),
    UNIT(test_dropped_byte_still_holds_the_wire),
    UNIT(test_silence_drops_and_deafens),
    UNIT(test_corrupt_next_and_drop_next_are_exact),
    UNIT(test_random_faults_reproduce_whatever_the_chunking)
)
