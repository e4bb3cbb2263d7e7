/* The FAP decoder's rejection reports (for fap monitor): every invalid
 * vector is reported with its reason and raw bytes, offsets are stream
 * offsets, good frames carry their raw bytes, a stale partial is a GAP. */
#include "fap/codec.h"
#include "fap_vectors.h"
#include "unit.h"

typedef struct {
    int reasons[64];
    size_t lens[64];
    uint64_t offs[64];
    int n;
    int frames;
    uint64_t frame_off[8];
    size_t frame_len[8];
} seen;

static void on_reject(void *ctx, int reason, const uint8_t *raw, size_t n, uint64_t off, lf_ns now)
{
    seen *s = ctx;
    (void)raw;
    (void)now;
    if (s->n < 64) {
        s->reasons[s->n] = reason;
        s->lens[s->n] = n;
        s->offs[s->n++] = off;
    }
}

static void on_frame(void *ctx, const lf_fap_frame *f, lf_ns now)
{
    seen *s = ctx;
    (void)now;
    if (s->frames < 8) {
        s->frame_off[s->frames] = f->offset;
        s->frame_len[s->frames] = f->raw_len;
    }
    s->frames++;
}

static int reason_of(const char *name)
{
    for (int r = LF_FAP_REJ_GARBAGE; r <= LF_FAP_REJ_GAP; r++)
        if (strcmp(lf_fap_reject_name(r), name) == 0)
            return r;
    return -1;
}

static void test_invalid_vectors_reasons(void)
{
    for (size_t i = 0; i < sizeof fapvec_invalid / sizeof fapvec_invalid[0]; i++) {
        const fapvec *v = &fapvec_invalid[i];
        lf_fap_decoder d;
        seen s = {0};
        lf_fap_decoder_init(&d, 0);
        lf_fap_decoder_on_reject(&d, on_reject, &s);
        lf_fap_decoder_feed(&d, (const uint8_t *)"\x00\x01", 2, 0, on_frame, &s);
        lf_fap_decoder_feed(&d, v->frame, v->frame_len, 0, on_frame, &s);
        REQUIRE(s.n >= 2);
        CHECK_EQ(s.reasons[0], LF_FAP_REJ_GARBAGE);
        CHECK_EQ(s.lens[0], 2);
        CHECK_EQ(s.reasons[1], reason_of(v->reason));
        CHECK_EQ(s.offs[1], 2);       /* the candidate starts after the garbage */
        CHECK(s.lens[1] >= 10 && s.lens[1] <= v->frame_len);
        CHECK_EQ(s.frames, 0);
    }
    CHECK_EQ(strcmp(lf_fap_reject_name(99), "?"), 0);
}

static void test_stream_frames_have_raw_and_offsets(void)
{
    lf_fap_decoder d;
    seen s = {0};
    lf_fap_decoder_init(&d, 0);
    lf_fap_decoder_on_reject(&d, on_reject, &s);
    for (size_t i = 0; i < fapvec_stream_len; i++)          /* byte by byte */
        lf_fap_decoder_feed(&d, fapvec_stream + i, 1, 0, on_frame, &s);
    CHECK_EQ(s.frames, 3);
    int crc = 0;
    for (int i = 0; i < s.n; i++)
        crc += s.reasons[i] == LF_FAP_REJ_CRC;
    CHECK_EQ(crc, (int)fapvec_stream_crc_errors);
    for (int i = 0; i < 3 && i < s.frames; i++)
        CHECK_MEM(fapvec_stream + s.frame_off[i], "cCtRsFe", 7);
    CHECK_EQ(s.frame_len[0], 15);
}

static void test_gap_reports_partial(void)
{
    lf_fap_decoder d;
    seen s = {0};
    lf_fap_decoder_init(&d, 1000);
    lf_fap_decoder_on_reject(&d, on_reject, &s);
    const fapvec *v = &fapvec_valid[1];
    lf_fap_decoder_feed(&d, v->frame, v->frame_len - 3, 5000, on_frame, &s);
    CHECK_EQ(s.n, 0);
    lf_fap_decoder_tick(&d, 5999, on_frame, &s);
    CHECK_EQ(s.n, 0);
    lf_fap_decoder_tick(&d, 6000, on_frame, &s);
    REQUIRE(s.n >= 1);
    CHECK_EQ(s.reasons[0], LF_FAP_REJ_GAP);
    CHECK_EQ(s.lens[0], v->frame_len - 3);
    CHECK_EQ(s.offs[0], 0);
    CHECK_EQ(d.c.gap_timeouts, 1);
    /* without a reject callback nothing changes for the engine */
    lf_fap_decoder_on_reject(&d, NULL, NULL);
    lf_fap_decoder_feed(&d, v->frame, v->frame_len, 7000, on_frame, &s);
    CHECK_EQ(s.frames, 1);
}

UNIT_MAIN(UNIT(test_invalid_vectors_reasons), UNIT(test_stream_frames_have_raw_and_offsets),
          UNIT(test_gap_reports_partial))
