/* lf_mikroc_scan (fap monitor's view of mikrocRS485_DecoderFeed): spans
 * and short reasons of good and bad frames. */
#include "mikroc/codec.h"
#include "unit.h"

static void feed_all(lf_mikroc_scan *s, const uint8_t *p, size_t n, int *codes, const char **why,
                     uint64_t *starts, uint64_t *ends, int *k)
{
    size_t used = 0;
    while (used < n) {
        used += lf_mikroc_scan_feed(s, p + used, n - used);
        if (s->code) {
            codes[*k] = s->code;
            why[*k] = s->reason;
            starts[*k] = s->rep_start;
            ends[*k] = s->rep_end;
            (*k)++;
            s->code = 0;
        }
    }
}

static void test_reasons_and_spans(void)
{
    /* garbage, a good frame, crc wrong, DATALEN bit 5, a frame cut by a start byte */
    const uint8_t in[] = {0x00, 0x01,
                          0x96, 0x97, 0xc2, 0x01, 0xa0, 0x0b, 0xa9,   /* 2..8 good */
                          0x96, 0xa0, 0x81, 0x02, 0xcc, 0xa9,         /* 9..14 crc */
                          0x96, 0x05, 0xa1,                           /* 15..17 datalen */
                          0x02, 0x59, 0xa9,                           /* noise */
                          0x96, 0x01,                                 /* 21..22 aborted */
                          0x96, 0xa0, 0x81, 0x02, 0xdc, 0xa9};        /* 23..28 good */
    lf_mikroc_scan s;
    lf_mikroc_scan_init(&s);
    int codes[8], k = 0;
    const char *why[8];
    uint64_t st[8], en[8];
    feed_all(&s, in, sizeof in, codes, why, st, en, &k);
    REQUIRE(k == 5);
    CHECK_EQ(codes[0], MIKROC_RS485_FRAME);
    CHECK(why[0] == NULL);
    CHECK_EQ(st[0], 2);
    CHECK_EQ(en[0], 9);
    CHECK_EQ(s.f.address, 160);
    CHECK_EQ(codes[1], MIKROC_RS485_ECRC);
    CHECK_EQ(strcmp(why[1], "crc"), 0);
    CHECK_EQ(st[1], 9);
    CHECK_EQ(en[1], 15);
    CHECK_EQ(codes[2], MIKROC_RS485_EFORMAT);
    CHECK_EQ(strcmp(why[2], "datalen"), 0);
    CHECK_EQ(en[2], 18);
    CHECK_EQ(codes[3], MIKROC_RS485_EABORT);
    CHECK_EQ(strcmp(why[3], "abort"), 0);
    CHECK_EQ(st[3], 21);
    CHECK_EQ(en[3], 23);
    CHECK_EQ(codes[4], MIKROC_RS485_FRAME);
    CHECK_EQ(st[4], 23);
    CHECK_EQ(en[4], sizeof in);
    CHECK(!lf_mikroc_scan_in_frame(&s));
    lf_mikroc_scan_feed(&s, in + 2, 3);
    CHECK(lf_mikroc_scan_in_frame(&s));
}

UNIT_MAIN(UNIT(test_reasons_and_spans))
