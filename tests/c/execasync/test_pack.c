/* execPackData / execUnPackData: a struct with u8/u16/u32/s32 members,
 * arrays and padding packs to the expected big-endian bytes and back, Ex
 * and in place; bad in-place descriptors change nothing. */
#include <stddef.h>
#include <stdint.h>

#include "exec_async.h"
#include "unit.h"

struct sample {
    uint8_t a;        /* padding after it */
    uint16_t b;
    uint8_t c;        /* padding after it */
    uint32_t d;
    int32_t e;
    uint8_t tag[3];   /* bytes, never reordered; padding after */
    int16_t f[2];
    uint64_t g;
};

static struct execStructDef VCONST sample_desc[] = {
    EXEC_STRUCT_ITEM(struct sample, a),
    EXEC_STRUCT_ITEM(struct sample, b),
    EXEC_STRUCT_ITEM(struct sample, c),
    EXEC_STRUCT_ITEM(struct sample, d),
    EXEC_STRUCT_ITEM(struct sample, e),
    EXEC_STRUCT_ARRAY(struct sample, tag),
    EXEC_STRUCT_ARRAY(struct sample, f),
    EXEC_STRUCT_ITEM(struct sample, g),
    EXEC_STRUCT_END(struct sample),
};

static const uint8_t sample_wire[] = {
    0x12,                                       /* a */
    0xAB, 0xCD,                                 /* b */
    0x7F,                                       /* c */
    0x01, 0x02, 0x03, 0x04,                     /* d */
    0xFF, 0xFF, 0xFF, 0xFE,                     /* e = -2 */
    'x', 'y', 'z',                              /* tag */
    0x80, 0x00, 0x00, 0x10,                     /* f = {-32768, 16} */
    0x01, 0x23, 0x45, 0x67, 0x89, 0xAB, 0xCD, 0xEF,  /* g */
};

static struct sample make_sample(void)
{
    struct sample s;
    memset(&s, 0, sizeof s);
    s.a = 0x12;
    s.b = 0xABCD;
    s.c = 0x7F;
    s.d = 0x01020304;
    s.e = -2;
    memcpy(s.tag, "xyz", 3);
    s.f[0] = -32768;
    s.f[1] = 16;
    s.g = 0x0123456789ABCDEFull;
    return s;
}

static int same_members(const struct sample *x, const struct sample *y)
{
    return x->a == y->a && x->b == y->b && x->c == y->c && x->d == y->d && x->e == y->e &&
           !memcmp(x->tag, y->tag, 3) && x->f[0] == y->f[0] && x->f[1] == y->f[1] &&
           x->g == y->g;
}

static void test_layout_has_padding(void)
{
    /* the point of the test: native and packed layouts differ */
    CHECK(sizeof(struct sample) > sizeof sample_wire);
    CHECK_EQ(offsetof(struct sample, b), 2);
    CHECK_EQ(sizeof sample_wire, 27);
}

static void test_pack_ex(void)
{
    struct sample s = make_sample();
    uint8_t wire[sizeof(struct sample) + 4];
    memset(wire, 0xEE, sizeof wire);
    word n = execPackDataEx(wire, (byte *)&s, sample_desc);
    CHECK_EQ(n, sizeof sample_wire);
    CHECK_MEM(wire, sample_wire, sizeof sample_wire);
    CHECK_EQ(wire[n], 0xEE);
}

static void test_unpack_ex(void)
{
    struct sample want = make_sample(), got;
    memset(&got, 0x5A, sizeof got);
    word n = execUnPackDataEx((byte *)&got, (byte *)sample_wire, sample_desc);
    CHECK_EQ(n, sizeof(struct sample));
    CHECK(same_members(&got, &want));
    /* padding is not written by the Ex form */
    CHECK_EQ(((uint8_t *)&got)[1], 0x5A);
}

static void test_round_trip_in_place(void)
{
    struct sample want = make_sample();
    union { struct sample s; uint8_t b[sizeof(struct sample)]; } u;
    u.s = want;
    word n = execPackData(u.b, sample_desc);
    CHECK_EQ(n, sizeof sample_wire);
    CHECK_MEM(u.b, sample_wire, sizeof sample_wire);
    n = execUnPackData(u.b, sample_desc);
    CHECK_EQ(n, sizeof(struct sample));
    CHECK(same_members(&u.s, &want));
}

static void test_round_trip_extremes(void)
{
    struct sample s;
    memset(&s, 0, sizeof s);
    s.a = 0xFF; s.b = 0xFFFF; s.c = 0; s.d = 0xFFFFFFFFu; s.e = INT32_MIN;
    s.f[0] = INT16_MAX; s.f[1] = -1; s.g = UINT64_MAX - 1;
    uint8_t wire[64];
    word n = execPackDataEx(wire, (byte *)&s, sample_desc);
    CHECK_EQ(n, 27);
    CHECK_EQ(wire[8], 0x80);   /* INT32_MIN big-endian: 80 00 00 00 */
    CHECK_EQ(wire[11], 0x00);
    struct sample back;
    memset(&back, 0, sizeof back);
    CHECK_EQ(execUnPackDataEx((byte *)&back, wire, sample_desc), sizeof back);
    CHECK(same_members(&back, &s));
}

/* Descriptor order is wire order for the Ex forms. */
static void test_ex_any_order(void)
{
    struct pair { uint16_t x; uint32_t y; } p = {0x1122, 0x33445566};
    static struct execStructDef VCONST reversed[] = {
        EXEC_STRUCT_ITEM(struct pair, y),
        EXEC_STRUCT_ITEM(struct pair, x),
        EXEC_STRUCT_END(struct pair),
    };
    uint8_t wire[8];
    CHECK_EQ(execPackDataEx(wire, (byte *)&p, reversed), 6);
    const uint8_t want[] = {0x33, 0x44, 0x55, 0x66, 0x11, 0x22};
    CHECK_MEM(wire, want, 6);
    struct pair q = {0, 0};
    CHECK_EQ(execUnPackDataEx((byte *)&q, wire, reversed), sizeof q);
    CHECK_EQ(q.x, 0x1122);
    CHECK_EQ(q.y, 0x33445566);
    /* in place refuses it and leaves the buffer alone */
    struct pair r = p;
    CHECK_EQ(execPackData((byte *)&r, reversed), 0);
    CHECK_MEM(&r, &p, sizeof p);
    CHECK_EQ(execUnPackData((byte *)&r, reversed), 0);
    CHECK_MEM(&r, &p, sizeof p);
}

/* Terminator Offset 0: UnPack returns the end of the last member. */
static void test_terminator_without_size(void)
{
    static struct execStructDef VCONST d[] = {{0, 2, 1}, {4, 4, 2}, {0, 0, 0}};
    uint8_t native[12] = {0}, wire[10] = {0};
    CHECK_EQ(execPackDataEx(wire, native, d), 10);
    CHECK_EQ(execUnPackDataEx(native, wire, d), 12);
}

static void test_opaque_item_size(void)
{
    /* a 3-byte item is copied as is; Count 0 counts as 1 */
    static struct execStructDef VCONST d[] = {{1, 3, 0}, {0, 0, 4}};
    uint8_t native[4] = {9, 1, 2, 3}, wire[3];
    CHECK_EQ(execPackDataEx(wire, native, d), 3);
    const uint8_t want[] = {1, 2, 3};
    CHECK_MEM(wire, want, 3);
    uint8_t back[4] = {0};
    CHECK_EQ(execUnPackDataEx(back, wire, d), 4);
    CHECK_MEM(back + 1, want, 3);
}

static void test_empty_descriptor(void)
{
    static struct execStructDef VCONST d[] = {{0, 0, 0}};
    uint8_t b[1] = {7};
    CHECK_EQ(execPackData(b, d), 0);
    CHECK_EQ(execUnPackData(b, d), 0);
    CHECK_EQ(b[0], 7);
}

/* Issue 12 defect 4: 80,000 bytes used to report 14,464 (80000 mod 65536).
 * The word-returning vendor functions report 0 and write nothing; the Wide
 * variants return the real size. */
static void test_size_beyond_word(void)
{
    enum { HALF = 40000, TOTAL = 2 * HALF };
    /* terminator 0: the native size is the furthest end, 80000 */
    static struct execStructDef VCONST big[] = {
        {0, 1, HALF}, {HALF, 2, HALF / 2}, {0, 0, 0},
    };
    byte *src = malloc(TOTAL), *dst = malloc(TOTAL), *back = malloc(TOTAL);
    REQUIRE(src && dst && back);
    for (unsigned i = 0; i < TOTAL; i++)
        src[i] = (byte)(i * 7 + 1);
    memset(dst, 0xAA, TOTAL);
    CHECK_EQ(execPackDataEx(dst, src, big), 0);          /* not 14464 */
    CHECK_EQ(dst[0], 0xAA);                              /* nothing written */
    CHECK_EQ(execPackDataExWide(dst, src, big), TOTAL);
    CHECK_EQ(execUnPackDataEx(back, dst, big), 0);
    CHECK_EQ(execUnPackDataExWide(back, dst, big), TOTAL);
    CHECK_MEM(back, src, TOTAL);                         /* round trip */
    memcpy(back, src, TOTAL);
    CHECK_EQ(execPackData(back, big), 0);
    CHECK_MEM(back, src, TOTAL);                         /* untouched */
    CHECK_EQ(execPackDataWide(back, big), TOTAL);
    CHECK_MEM(back, dst, TOTAL);
    CHECK_EQ(execUnPackData(back, big), 0);
    CHECK_EQ(execUnPackDataWide(back, big), TOTAL);
    CHECK_MEM(back, src, TOTAL);
    free(src);
    free(dst);
    free(back);
}

UNIT_MAIN(UNIT(test_size_beyond_word), UNIT(test_layout_has_padding), UNIT(test_pack_ex), UNIT(test_unpack_ex),
          UNIT(test_round_trip_in_place), UNIT(test_round_trip_extremes),
          UNIT(test_ex_any_order), UNIT(test_terminator_without_size),
          UNIT(test_opaque_item_size), UNIT(test_empty_descriptor))
