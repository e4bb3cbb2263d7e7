/* Exec async framing: byte-exact against tests/vectors/exec_async.json,
 * decoder results for good, corrupted, overflowing and broken frames, and
 * resynchronisation after each. */
#include <stdlib.h>

#include "exec_async.h"
#include "unit.h"
#include "vectors.h"

static exec_vector valid[16], invalid[8];
static size_t n_valid, n_invalid;

static void load_vectors(void)
{
    const char *path = getenv("EXEC_VECTORS");
    char *text = path ? vec_read_file(path) : NULL;
    if (!text) {
        fprintf(stderr, "EXEC_VECTORS=%s: cannot read\n", path ? path : "(unset)");
        return;
    }
    n_valid = vec_load(text, "valid", valid, 16);
    n_invalid = vec_load(text, "invalid", invalid, 8);
    free(text);
}

/* Feed n bytes; count true returns; remember the last report. */
typedef struct feed_result {
    int reports;
    size_t last_at;           /* index of the byte that gave the last true */
    struct execAsyncStateDef last;
} feed_result;

static feed_result feed(struct execAsyncStateDef *st, uint8_t *buf, const uint8_t *in, size_t n)
{
    feed_result r = {0};
    for (size_t i = 0; i < n; i++) {
        if (execAsyncByteIn(in[i], st, buf)) {
            r.reports++;
            r.last_at = i;
            r.last = *st;
        }
    }
    return r;
}

static void test_vectors_loaded(void)
{
    CHECK_EQ(n_valid, 7);
    CHECK_EQ(n_invalid, 1);
}

static void test_encode_byte_exact(void)
{
    for (size_t i = 0; i < n_valid; i++) {
        const exec_vector *v = &valid[i];
        uint8_t tx[EXEC_ASYNC_MAX_FRAME + 16];
        memset(tx, 0xEE, sizeof tx);
        word n = execAsyncBufferOut((byte)v->node, (byte *)v->data, tx, (byte)v->data_len,
                                    (byte)v->seq);
        CHECK_EQ(n, v->frame_len);
        CHECK_MEM(tx, v->frame, v->frame_len);
        CHECK(n <= EXEC_ASYNC_FRAME_SIZE(v->data_len));
        CHECK_EQ(tx[n], 0xEE);   /* nothing written past the frame */
    }
}

static void test_node_and_seq_dle_sent_raw(void)
{
    uint8_t tx[16];
    byte d = 0x10;
    word n = execAsyncBufferOut(0x10, &d, tx, 1, 0x10);
    const uint8_t want[] = {0x10, 0x02, 0x10, 0x10, 0x10, 0x10, 0x10, 0x03, 0x09, 0x09};
    CHECK_EQ(n, sizeof want);
    CHECK_MEM(tx, want, sizeof want);
}

static void test_worst_case_length(void)
{
    byte raw[EXEC_ASYNC_MAX_DATA];
    memset(raw, 0x10, sizeof raw);
    byte *tx = malloc(EXEC_ASYNC_MAX_FRAME);   /* exact size: asan sees any overrun */
    REQUIRE(tx);
    CHECK_EQ(EXEC_ASYNC_MAX_FRAME, 518);
    for (unsigned len = 0; len <= EXEC_ASYNC_MAX_DATA; len += 15)
        CHECK_EQ(execAsyncBufferOut(3, raw, tx, (byte)len, 255), 2 * len + 8);
    CHECK_EQ(execAsyncBufferOut(3, raw, tx, 255, 255), 518);
    struct execAsyncStateDef st = {0};
    byte *buf = malloc(EXEC_ASYNC_MAX_DATA);
    REQUIRE(buf);
    feed_result r = feed(&st, buf, tx, 518);
    CHECK_EQ(r.reports, 1);
    CHECK_EQ(r.last.Status, EXEC_ASYNC_GOOD);
    CHECK_EQ(r.last.Length, 255);
    CHECK_MEM(buf, raw, 255);
    free(buf);
    free(tx);
}

static void test_empty_payload_null_raw(void)
{
    uint8_t tx[8];
    CHECK_EQ(execAsyncBufferOut(1, NULL, tx, 0, 0), 8);
    const uint8_t want[] = {0x10, 0x02, 0x01, 0x00, 0x10, 0x03, 0x90, 0x01};
    CHECK_MEM(tx, want, 8);
}

static void test_decode_each_vector(void)
{
    for (size_t i = 0; i < n_valid; i++) {
        const exec_vector *v = &valid[i];
        struct execAsyncStateDef st;
        memset(&st, 0, sizeof st);   /* zero-filled = initial state */
        uint8_t buf[EXEC_ASYNC_MAX_DATA];
        feed_result r = feed(&st, buf, v->frame, v->frame_len);
        CHECK_EQ(r.reports, 1);
        CHECK_EQ(r.last_at, v->frame_len - 1);   /* true on the last CRC byte only */
        CHECK_EQ(r.last.Status, EXEC_ASYNC_GOOD);
        CHECK_EQ(r.last.Node, v->node);
        CHECK_EQ(r.last.SeqNo, v->seq);
        CHECK_EQ(r.last.Length, v->data_len);
        CHECK_MEM(buf, v->data, v->data_len);
    }
}

static void test_decode_invalid_vectors(void)
{
    for (size_t i = 0; i < n_invalid; i++) {
        struct execAsyncStateDef st = {0};
        uint8_t buf[EXEC_ASYNC_MAX_DATA];
        feed_result r = feed(&st, buf, invalid[i].frame, invalid[i].frame_len);
        CHECK_EQ(r.reports, 1);
        CHECK(strcmp(invalid[i].reason, "crc") == 0);
        CHECK_EQ(r.last.Status, EXEC_ASYNC_BAD_CRC);
        CHECK_EQ(r.last.Node, 5);
        CHECK_EQ(r.last.Length, 3);
    }
}

/* All vectors back to back with noise between: one state decodes them all. */
static void test_stream_with_noise(void)
{
    static uint8_t stream[8192];
    size_t n = 0;
    const uint8_t noise[] = {0x00, 0xFF, 0x10, 0x10, 0x03, 0x55, 0x10};
    for (size_t i = 0; i < n_valid; i++) {
        memcpy(stream + n, noise, sizeof noise);
        n += sizeof noise;
        memcpy(stream + n, valid[i].frame, valid[i].frame_len);
        n += valid[i].frame_len;
    }
    struct execAsyncStateDef st = {0};
    uint8_t buf[EXEC_ASYNC_MAX_DATA];
    size_t got = 0;
    for (size_t i = 0; i < n; i++) {
        if (!execAsyncByteIn(stream[i], &st, buf))
            continue;
        REQUIRE(got < n_valid);
        CHECK_EQ(st.Status, EXEC_ASYNC_GOOD);
        CHECK_EQ(st.Node, valid[got].node);
        CHECK_EQ(st.SeqNo, valid[got].seq);
        CHECK_EQ(st.Length, valid[got].data_len);
        CHECK_MEM(buf, valid[got].data, valid[got].data_len);
        got++;
    }
    CHECK_EQ(got, n_valid);
}

/* Flip every bit of a frame in turn: never GOOD, and the good frame that
 * follows is always decoded. */
static void test_every_single_bit_error_caught(void)
{
    const exec_vector *v = &valid[2];   /* data with DLEs: the hardest case */
    uint8_t next[32];
    byte d[] = {1, 2, 3};
    word next_len = execAsyncBufferOut(9, d, next, 3, 42);
    for (size_t byte_i = 0; byte_i < v->frame_len; byte_i++) {
        for (int bit = 0; bit < 8; bit++) {
            uint8_t f[64];
            memcpy(f, v->frame, v->frame_len);
            f[byte_i] ^= (uint8_t)(1u << bit);
            struct execAsyncStateDef st = {0};
            uint8_t buf[EXEC_ASYNC_MAX_DATA];
            int good_bad = 0, good_next = 0;
            for (size_t i = 0; i < v->frame_len; i++)
                if (execAsyncByteIn(f[i], &st, buf) && st.Status == EXEC_ASYNC_GOOD)
                    good_bad++;
            for (size_t i = 0; i < next_len; i++)
                if (execAsyncByteIn(next[i], &st, buf) && st.Status == EXEC_ASYNC_GOOD &&
                    st.Node == 9 && st.SeqNo == 42 && st.Length == 3 && !memcmp(buf, d, 3))
                    good_next++;
            if (good_bad != 0 || good_next != 1)
                fprintf(stderr, "byte %zu bit %d: good_bad %d good_next %d\n", byte_i, bit,
                        good_bad, good_next);
            CHECK_EQ(good_bad, 0);
            CHECK_EQ(good_next, 1);
        }
    }
}

static void test_overflow_small_buffer(void)
{
    byte raw[8] = {1, 2, 3, 0x10, 5, 6, 7, 8};
    uint8_t tx[32], tx2[32];
    word n = execAsyncBufferOut(4, raw, tx, 8, 1);
    word n2 = execAsyncBufferOut(4, raw, tx2, 3, 2);
    struct execAsyncStateDef st = {0};
    st.BufferSize = 3;
    byte *buf = malloc(3);
    REQUIRE(buf);
    feed_result r = feed(&st, buf, tx, n);
    CHECK_EQ(r.reports, 1);
    CHECK_EQ(r.last.Status, EXEC_ASYNC_OVERFLOW);
    CHECK_EQ(r.last.Length, 3);
    CHECK_EQ(r.last.Node, 4);
    CHECK_MEM(buf, raw, 3);
    CHECK_EQ(st.BufferSize, 3);   /* configuration survives */
    r = feed(&st, buf, tx2, n2);  /* still in step: the next frame is good */
    CHECK_EQ(r.reports, 1);
    CHECK_EQ(r.last.Status, EXEC_ASYNC_GOOD);
    CHECK_EQ(r.last.SeqNo, 2);
    CHECK_MEM(buf, raw, 3);
    free(buf);
}

static void test_overflow_default_buffer(void)
{
    /* a hand-made frame with 300 data bytes: more than any sender makes */
    static uint8_t f[700];
    size_t n = 0;
    f[n++] = 0x10; f[n++] = 0x02; f[n++] = 7; f[n++] = 1;
    for (int i = 0; i < 300; i++)
        f[n++] = (uint8_t)(0x20 + i % 50);
    f[n++] = 0x10; f[n++] = 0x03; f[n++] = 0; f[n++] = 0;
    struct execAsyncStateDef st = {0};
    byte *buf = malloc(EXEC_ASYNC_MAX_DATA);
    REQUIRE(buf);
    feed_result r = feed(&st, buf, f, n);
    CHECK_EQ(r.reports, 1);
    CHECK_EQ(r.last.Status, EXEC_ASYNC_OVERFLOW);
    CHECK_EQ(r.last.Length, 255);
    CHECK_EQ(r.last_at, 4 + 255);   /* reported at the first byte that does not fit */
    r = feed(&st, buf, valid[1].frame, valid[1].frame_len);
    CHECK_EQ(r.reports, 1);
    CHECK_EQ(r.last.Status, EXEC_ASYNC_GOOD);
    free(buf);
}

static void test_framing_bad_escape(void)
{
    const uint8_t f[] = {0x10, 0x02, 1, 1, 0x41, 0x10, 0x05, 0x42, 0x10, 0x03, 0, 0};
    struct execAsyncStateDef st = {0};
    uint8_t buf[EXEC_ASYNC_MAX_DATA];
    feed_result r = feed(&st, buf, f, sizeof f);
    CHECK_EQ(r.reports, 1);
    CHECK_EQ(r.last_at, 6);
    CHECK_EQ(r.last.Status, EXEC_ASYNC_FRAMING);
    r = feed(&st, buf, valid[0].frame, valid[0].frame_len);
    CHECK_EQ(r.reports, 1);
    CHECK_EQ(r.last.Status, EXEC_ASYNC_GOOD);
}

/* A frame cut short by the next DLE STX: FRAMING, then the new frame. */
static void test_truncated_then_good(void)
{
    uint8_t f[64];
    size_t n = 0;
    memcpy(f, valid[1].frame, 6);        /* DLE STX node seq 'A' 'B' */
    n = 6;
    memcpy(f + n, valid[2].frame, valid[2].frame_len);
    n += valid[2].frame_len;
    struct execAsyncStateDef st = {0};
    uint8_t buf[EXEC_ASYNC_MAX_DATA];
    int reports = 0;
    for (size_t i = 0; i < n; i++) {
        if (!execAsyncByteIn(f[i], &st, buf))
            continue;
        reports++;
        if (reports == 1) {
            CHECK_EQ(i, 7);              /* at the STX of the second frame */
            CHECK_EQ(st.Status, EXEC_ASYNC_FRAMING);
            CHECK_EQ(st.Node, 5);
            CHECK_EQ(st.Length, 2);
        } else {
            CHECK_EQ(st.Status, EXEC_ASYNC_GOOD);
            CHECK_EQ(st.Node, valid[2].node);
            CHECK_EQ(st.Length, valid[2].data_len);
            CHECK_MEM(buf, valid[2].data, valid[2].data_len);
        }
    }
    CHECK_EQ(reports, 2);
}

static void test_round_trip_all_lengths(void)
{
    srand(7);
    byte raw[EXEC_ASYNC_MAX_DATA];
    byte tx[EXEC_ASYNC_MAX_FRAME];
    struct execAsyncStateDef st = {0};
    uint8_t buf[EXEC_ASYNC_MAX_DATA];
    int ok = 0;
    for (unsigned len = 0; len <= 255; len++) {
        for (unsigned i = 0; i < len; i++)
            raw[i] = (byte)(rand() % 4 == 0 ? 0x10 : rand());
        byte node = (byte)(len % 256), seq = (byte)(255 - len);
        word n = execAsyncBufferOut(node, raw, tx, (byte)len, seq);
        feed_result r = feed(&st, buf, tx, n);
        ok += r.reports == 1 && r.last.Status == EXEC_ASYNC_GOOD && r.last.Node == node &&
              r.last.SeqNo == seq && r.last.Length == len && !memcmp(buf, raw, len);
    }
    CHECK_EQ(ok, 256);
}

int main(void)
{
    load_vectors();
    static const unit_test tests[] = {
        UNIT(test_vectors_loaded),
        UNIT(test_encode_byte_exact),
        UNIT(test_node_and_seq_dle_sent_raw),
        UNIT(test_worst_case_length),
        UNIT(test_empty_payload_null_raw),
        UNIT(test_decode_each_vector),
        UNIT(test_decode_invalid_vectors),
        UNIT(test_stream_with_noise),
        UNIT(test_every_single_bit_error_caught),
        UNIT(test_overflow_small_buffer),
        UNIT(test_overflow_default_buffer),
        UNIT(test_framing_bad_escape),
        UNIT(test_truncated_then_good),
        UNIT(test_round_trip_all_lengths),
    };
    return unit_run(tests, sizeof tests / sizeof tests[0]);
}
