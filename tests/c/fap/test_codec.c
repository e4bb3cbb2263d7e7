/* FAP codec: byte-exact against vectors/fap.json, any chunking, resync
 * after garbage and bad frames, inter-byte gap, both marker spellings. */
#include "fap/codec.h"
#include "fap_vectors.h"
#include "unit.h"

#define MAXF 64
typedef struct {
    int n;
    struct { int msg, dst, src; size_t len; uint8_t data[LF_FAP_MAX_DATA]; } f[MAXF];
} sink;

static void on_frame(void *ctx, const lf_fap_frame *f, lf_ns now)
{
    (void)now;
    sink *s = ctx;
    if (s->n >= MAXF)
        return;
    s->f[s->n].msg = f->msg;
    s->f[s->n].dst = f->dst;
    s->f[s->n].src = f->src;
    s->f[s->n].len = f->len;
    memcpy(s->f[s->n].data, f->data, f->len);
    s->n++;
}

static unsigned rng_state = 12345;
static unsigned rnd(void)
{
    rng_state = rng_state * 1103515245u + 12345u;
    return (rng_state >> 16) & 0x7fff;
}

/* Feed in chunks: mode 0 whole, 1 byte by byte, 2 random 1..40. */
static void feed_chunked(lf_fap_decoder *d, const uint8_t *p, size_t n, int mode, sink *s)
{
    size_t i = 0;
    while (i < n) {
        size_t k = mode == 0 ? n : mode == 1 ? 1 : 1 + rnd() % 40;
        if (k > n - i)
            k = n - i;
        lf_fap_decoder_feed(d, p + i, k, 1000, on_frame, s);
        i += k;
    }
}

static void test_encode_vectors(void)
{
    uint8_t buf[LF_FAP_MAX_FRAME];
    for (size_t i = 0; i < sizeof fapvec_valid / sizeof fapvec_valid[0]; i++) {
        const fapvec *v = &fapvec_valid[i];
        size_t n = lf_fap_encode(buf, sizeof buf, v->msg, v->dst, v->src, v->data, v->len);
        CHECK_EQ(n, v->frame_len);
        CHECK_MEM(buf, v->frame, v->frame_len);
    }
}

static void test_encode_rejects(void)
{
    uint8_t buf[LF_FAP_MAX_FRAME], d[1025] = { 0 };
    CHECK_EQ(lf_fap_encode(buf, sizeof buf, 5, 1, 0, NULL, 0), 0);
    CHECK_EQ(lf_fap_encode(buf, sizeof buf, LF_FAP_DATA, 1, 0, d, 0), 0);
    CHECK_EQ(lf_fap_encode(buf, sizeof buf, LF_FAP_DATA, 1, 0, d, 1025), 0);
    CHECK_EQ(lf_fap_encode(buf, sizeof buf, LF_FAP_QUERY_ID, 1, 0, d, 1), 0);
    CHECK_EQ(lf_fap_encode(buf, 14, LF_FAP_QUERY_ID, 1, 0, NULL, 0), 0);
    CHECK_EQ(lf_fap_encode(buf, 15, LF_FAP_QUERY_ID, 1, 0, NULL, 0), 15);
    CHECK_EQ(lf_fap_encode(buf, sizeof buf, LF_FAP_DATA, 1, 0, d, 1024), 1039);
}

static void test_decode_vectors_any_chunking(void)
{
    for (int mode = 0; mode < 3; mode++) {
        for (size_t i = 0; i < sizeof fapvec_valid / sizeof fapvec_valid[0]; i++) {
            const fapvec *v = &fapvec_valid[i];
            lf_fap_decoder d;
            static sink s;
            s.n = 0;
            lf_fap_decoder_init(&d, 10 * LF_NS_PER_MS);
            feed_chunked(&d, v->frame, v->frame_len, mode, &s);
            REQUIRE(s.n == 1);
            CHECK_EQ(s.f[0].msg, v->msg);
            CHECK_EQ(s.f[0].dst, v->dst);
            CHECK_EQ(s.f[0].src, v->src);
            CHECK_EQ(s.f[0].len, v->len);
            CHECK_MEM(s.f[0].data, v->data, v->len);
            CHECK_EQ(d.n, 0);
            CHECK_EQ(d.c.frames, 1);
        }
    }
}

static void test_decode_invalid_vectors(void)
{
    for (size_t i = 0; i < sizeof fapvec_invalid / sizeof fapvec_invalid[0]; i++) {
        const fapvec *v = &fapvec_invalid[i];
        lf_fap_decoder d;
        static sink s;
        s.n = 0;
        lf_fap_decoder_init(&d, 10 * LF_NS_PER_MS);
        lf_fap_decoder_feed(&d, v->frame, v->frame_len, 1000, on_frame, &s);
        /* followed by a good frame: it must still come out */
        const fapvec *g = &fapvec_valid[0];
        lf_fap_decoder_feed(&d, g->frame, g->frame_len, 1000, on_frame, &s);
        REQUIRE(s.n == 1);
        CHECK_EQ(s.f[0].msg, g->msg);
        CHECK_EQ(s.f[0].dst, g->dst);
        if (strcmp(v->reason, "crc") == 0)
            CHECK_EQ(d.c.crc_errors, 1);
        else
            CHECK_EQ(d.c.framing_errors, 1);
    }
}

static void test_alternate_marker(void)
{
    lf_fap_decoder d;
    static sink s;
    s.n = 0;
    lf_fap_decoder_init(&d, 10 * LF_NS_PER_MS);
    feed_chunked(&d, fapvec_alt.frame, fapvec_alt.frame_len, 1, &s);
    REQUIRE(s.n == 1);
    CHECK_EQ(s.f[0].msg, fapvec_alt.msg);
    CHECK_EQ(s.f[0].src, fapvec_alt.src);
    CHECK_MEM(s.f[0].data, fapvec_alt.data, fapvec_alt.len);
}

static void test_stream_vector(void)
{
    for (int mode = 0; mode < 3; mode++) {
        for (int rep = 0; rep < (mode == 2 ? 50 : 1); rep++) {
            lf_fap_decoder d;
            static sink s;
            s.n = 0;
            lf_fap_decoder_init(&d, 10 * LF_NS_PER_MS);
            feed_chunked(&d, fapvec_stream, fapvec_stream_len, mode, &s);
            size_t nf = sizeof fapvec_stream_frames / sizeof fapvec_stream_frames[0];
            REQUIRE(s.n == (int)nf);
            for (size_t i = 0; i < nf; i++) {
                CHECK_EQ(s.f[i].msg, fapvec_stream_frames[i].msg);
                CHECK_EQ(s.f[i].dst, fapvec_stream_frames[i].dst);
                CHECK_EQ(s.f[i].src, fapvec_stream_frames[i].src);
                CHECK_EQ(s.f[i].len, fapvec_stream_frames[i].len);
                CHECK_MEM(s.f[i].data, fapvec_stream_frames[i].data, s.f[i].len);
            }
            CHECK_EQ(d.c.crc_errors, fapvec_stream_crc_errors);
        }
    }
}

/* A truncated frame claiming a large size must not swallow the good frame
 * behind it: after the inter-byte gap the rescan finds it. */
static void test_truncated_frame_then_good_frame(void)
{
    uint8_t big[LF_FAP_MAX_FRAME], buf[2 * LF_FAP_MAX_FRAME], data[300];
    memset(data, 0x55, sizeof data);
    size_t nb = lf_fap_encode(big, sizeof big, LF_FAP_DATA, 2, 1, data, sizeof data);
    const fapvec *g = &fapvec_valid[1];
    memcpy(buf, big, 40);                       /* only 40 of 315 bytes arrive */
    memcpy(buf + 40, g->frame, g->frame_len);
    lf_fap_decoder d;
    static sink s;
    s.n = 0;
    lf_fap_decoder_init(&d, 10 * LF_NS_PER_MS);
    lf_fap_decoder_feed(&d, buf, 40 + g->frame_len, 1000, on_frame, &s);
    CHECK_EQ(s.n, 0);                           /* held: could still be the big frame */
    CHECK_EQ(lf_fap_decoder_deadline(&d), 1000 + 10 * LF_NS_PER_MS);
    lf_fap_decoder_tick(&d, 1000 + 10 * LF_NS_PER_MS - 1, on_frame, &s);
    CHECK_EQ(s.n, 0);
    lf_fap_decoder_tick(&d, 1000 + 10 * LF_NS_PER_MS, on_frame, &s);
    REQUIRE(s.n == 1);
    CHECK_EQ(s.f[0].src, g->src);
    CHECK_MEM(s.f[0].data, g->data, g->len);
    CHECK_EQ(d.c.gap_timeouts, 1);
    CHECK_EQ(d.n, 0);
    CHECK_EQ(lf_fap_decoder_deadline(&d), LF_NEVER);
    (void)nb;
}

/* A partial frame, an idle line (tick at the gap), then a new frame. And
 * without the tick (a late reader): the CRC still resynchronises. */
static void test_gap_then_new_frame(void)
{
    uint8_t q[LF_FAP_MAX_FRAME];
    size_t nq = lf_fap_encode(q, sizeof q, LF_FAP_QUERY_ID, 5, 0, NULL, 0);
    lf_fap_decoder d;
    static sink s;
    s.n = 0;
    lf_fap_decoder_init(&d, 2 * LF_NS_PER_MS);
    lf_fap_decoder_feed(&d, q, 9, 0, on_frame, &s);               /* partial */
    lf_fap_decoder_tick(&d, 2 * LF_NS_PER_MS, on_frame, &s);
    CHECK_EQ(d.c.gap_timeouts, 1);
    CHECK_EQ(d.n, 0);
    lf_fap_decoder_feed(&d, q, nq, 5 * LF_NS_PER_MS, on_frame, &s);
    REQUIRE(s.n == 1);
    CHECK_EQ(s.f[0].dst, 5);
    lf_fap_decoder_feed(&d, q, 9, 6 * LF_NS_PER_MS, on_frame, &s);  /* partial, no tick */
    lf_fap_decoder_feed(&d, q, nq, 9 * LF_NS_PER_MS, on_frame, &s);
    REQUIRE(s.n == 2);
    CHECK_EQ(s.f[1].dst, 5);
    CHECK(d.c.framing_errors + d.c.crc_errors >= 1);
    s.n = 1;
    /* a slow frame within the gap per byte still decodes */
    for (size_t i = 0; i < nq; i++)
        lf_fap_decoder_feed(&d, q + i, 1, 10 * LF_NS_PER_MS + (lf_ns)i * LF_NS_PER_MS, on_frame, &s);
    CHECK_EQ(s.n, 2);
}

static void test_default_gap(void)
{
    CHECK_EQ(lf_fap_default_gap(115200), 10 * LF_NS_PER_MS);
    CHECK_EQ(lf_fap_default_gap(1200), 4 * lf_char_time_ns(1200));
    CHECK_EQ(lf_fap_default_gap(0), 10 * LF_NS_PER_MS);
}

/* Random garbage between random valid frames, random chunking. */
static void test_fuzz_garbage_between_frames(void)
{
    static uint8_t stream[200000];
    static struct { int msg, dst, src; size_t len; uint8_t data[64]; } want[400];
    size_t n = 0;
    int nw = 0;
    for (int i = 0; i < 400; i++) {
        size_t g = rnd() % 30;
        for (size_t k = 0; k < g; k++) {
            uint8_t b = (uint8_t)rnd();
            stream[n++] = (rnd() % 4 == 0) ? (uint8_t)"cCtRsFeF"[rnd() % 7] : b;
        }
        int msg = rnd() % 5;
        size_t len = msg == LF_FAP_DATA ? 1 + rnd() % 64 : 0;
        want[nw].msg = msg;
        want[nw].dst = rnd() % 32;
        want[nw].src = rnd() % 32;
        want[nw].len = len;
        for (size_t k = 0; k < len; k++)
            want[nw].data[k] = (uint8_t)rnd();
        n += lf_fap_encode(stream + n, sizeof stream - n, msg, want[nw].dst, want[nw].src,
                           want[nw].data, len);
        nw++;
    }
    lf_fap_decoder d;
    static sink s;
    s.n = 0;
    lf_fap_decoder_init(&d, 10 * LF_NS_PER_MS);
    /* sink holds 64: check in batches */
    size_t i = 0;
    int seen = 0, bad = 0;
    while (i < n) {
        size_t k = 1 + rnd() % 50;
        if (k > n - i)
            k = n - i;
        lf_fap_decoder_feed(&d, stream + i, k, 1000, on_frame, &s);
        i += k;
        for (int j = 0; j < s.n; j++, seen++) {
            if (seen >= nw || s.f[j].msg != want[seen].msg || s.f[j].dst != want[seen].dst ||
                s.f[j].src != want[seen].src || s.f[j].len != want[seen].len ||
                memcmp(s.f[j].data, want[seen].data, s.f[j].len) != 0)
                bad++;
        }
        s.n = 0;
    }
    CHECK_EQ(seen, nw);
    CHECK_EQ(bad, 0);
    CHECK(d.c.garbage_bytes > 0);
}

/* Corrupt one byte anywhere in a frame: that frame is lost, the next one is not. */
static void test_single_corruption_never_swallows_next(void)
{
    uint8_t a[LF_FAP_MAX_FRAME], b[LF_FAP_MAX_FRAME], buf[2 * LF_FAP_MAX_FRAME];
    uint8_t data[20];
    memset(data, 0xA5, sizeof data);
    size_t na = lf_fap_encode(a, sizeof a, LF_FAP_DATA, 3, 1, data, sizeof data);
    size_t nb = lf_fap_encode(b, sizeof b, LF_FAP_DATA_DONE, 0, 1, NULL, 0);
    int failures = 0;
    for (size_t pos = 0; pos < na; pos++) {
        for (int bit = 0; bit < 8; bit++) {
            memcpy(buf, a, na);
            memcpy(buf + na, b, nb);
            buf[pos] ^= (uint8_t)(1u << bit);
            lf_fap_decoder d;
            static sink s;
            s.n = 0;
            lf_fap_decoder_init(&d, 10 * LF_NS_PER_MS);
            lf_fap_decoder_feed(&d, buf, na + nb, 1000, on_frame, &s);
            lf_fap_decoder_tick(&d, 1000 + 10 * LF_NS_PER_MS, on_frame, &s);
            int got_b = s.n >= 1 && s.f[s.n - 1].msg == LF_FAP_DATA_DONE;
            int got_a = s.n >= 1 && s.f[0].msg == LF_FAP_DATA;
            int alt_marker = pos == 7 && bit == 5;     /* 'F' -> 'f': still valid */
            if (!got_b || got_a != alt_marker)
                failures++;
        }
    }
    CHECK_EQ(failures, 0);
}

UNIT_MAIN(UNIT(test_encode_vectors), UNIT(test_encode_rejects),
          UNIT(test_decode_vectors_any_chunking), UNIT(test_decode_invalid_vectors),
          UNIT(test_alternate_marker), UNIT(test_stream_vector),
          UNIT(test_truncated_frame_then_good_frame), UNIT(test_gap_then_new_frame),
          UNIT(test_default_gap), UNIT(test_fuzz_garbage_between_frames),
          UNIT(test_single_corruption_never_swallows_next))
