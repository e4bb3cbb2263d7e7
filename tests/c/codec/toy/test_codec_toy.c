/* A row added from its own file only (tests/c/codec/toy/codec_table.c):
 * the table generated from the components list plus the toy has it last,
 * fap_codec_find() finds it by name and by the alias its row declares, it
 * decodes through the table's face, and every built-in row is still there
 * (the built-ins' own aliases too). */
#include <stdint.h>

#include "fap_codec.h"
#include "unit.h"

typedef struct seen {
    int frames, rejects, garbage;
    unsigned len;
    uint8_t data[8];
} seen;

static void on_frame(void *ctx, const fap_codec_frame *f)
{
    seen *s = ctx;
    s->frames++;
    s->len = f->field[0];
    memcpy(s->data, f->data, f->data_len < 8 ? f->data_len : 8);
}

static void on_reject(void *ctx, int code, const uint8_t *raw, size_t n, uint64_t offset)
{
    (void)raw;
    (void)n;
    (void)offset;
    seen *s = ctx;
    if (code == FAP_CODEC_GARBAGE)
        s->garbage++;
    else
        s->rejects++;
}

static void test_toy_is_a_row(void)
{
    size_t n = 0;
    const fap_codec *c, *last = NULL;
    for (; (c = fap_codec_at(n)) != NULL; n++) {
        CHECK(fap_codec_find(c->name) == c);
        last = c;
    }
    CHECK_EQ(n, LF_CODEC_N_ROWS);
    REQUIRE(last != NULL);
    CHECK_EQ(strcmp(last->name, "toy"), 0);
    CHECK(fap_codec_find("toy") == last);
    CHECK(fap_codec_find("toyish") == last);           /* the alias its own row declares */
    CHECK(fap_codec_find("execasync") == fap_codec_find("exec"));   /* and the built-ins' */
    CHECK(fap_codec_find("exec") != NULL && fap_codec_find("exec") != last);
    CHECK(fap_codec_find("toys") == NULL);
    CHECK(fap_codec_at(n) == NULL);
}

static void test_toy_decodes(void)
{
    const fap_codec *c = fap_codec_find("toy");
    REQUIRE(c != NULL);
    uint8_t st[64], wire[32];
    REQUIRE(c->state_size <= sizeof st);
    unsigned field[FAP_CODEC_MAX_FIELDS] = {3};
    size_t n = c->encode(wire + 1, sizeof wire - 1, field, (const uint8_t *)"abc", 3);
    CHECK_EQ(n, 6);
    wire[0] = 'x';                                     /* garbage first */
    seen s = {0};
    c->init(st, 9600, 0);
    c->feed(st, wire, n + 1, 1, on_frame, on_reject, &s);
    c->finish(st, on_frame, on_reject, &s);
    CHECK_EQ(s.frames, 1);
    CHECK_EQ(s.garbage, 1);
    CHECK_EQ(s.rejects, 0);
    CHECK_EQ(s.len, 3);
    CHECK_MEM(s.data, "abc", 3);
    CHECK_EQ(strcmp(c->reject_name(FAP_CODEC_TRUNCATED), "truncated"), 0);
}

UNIT_MAIN(UNIT(test_toy_is_a_row), UNIT(test_toy_decodes))
