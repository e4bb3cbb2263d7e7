/* CRC catalogue check values: CCITT-FALSE("123456789") = 0x29B1,
 * ARC("123456789") = 0xBB3D; chunked updates equal one pass. */
#include "common/crc16.h"
#include "common/mono_clock.h"
#include "unit.h"

static const uint8_t check[] = "123456789";

static void test_ccitt_false_check_value(void)
{
    CHECK_EQ(lf_crc16_ccitt(check, 9), 0x29B1);
    CHECK_EQ(lf_crc16_ccitt(check, 0), 0xFFFF);
}

static void test_arc_check_value(void)
{
    CHECK_EQ(lf_crc16_arc(check, 9), 0xBB3D);
    CHECK_EQ(lf_crc16_arc(check, 0), 0);
}

static void test_chunked_updates(void)
{
    uint16_t c = lf_crc16_ccitt_update(LF_CRC_CCITT_INIT, check, 4);
    CHECK_EQ(lf_crc16_ccitt_update(c, check + 4, 5), 0x29B1);
    uint16_t a = lf_crc16_arc_update(0, check, 2);
    CHECK_EQ(lf_crc16_arc_update(a, check + 2, 7), 0xBB3D);
}

static void test_poll_timeout_rounding(void)
{
    CHECK_EQ(lf_poll_timeout_ms(LF_NEVER, 0), -1);
    CHECK_EQ(lf_poll_timeout_ms(100, 200), 0);
    CHECK_EQ(lf_poll_timeout_ms(1, 0), 1);              /* never wake early */
    CHECK_EQ(lf_poll_timeout_ms(LF_NS_PER_MS, 0), 1);
    CHECK_EQ(lf_poll_timeout_ms(LF_NS_PER_MS + 1, 0), 2);
    CHECK_EQ(lf_char_time_ns(9600), 1041666);
}

UNIT_MAIN(UNIT(test_ccitt_false_check_value), UNIT(test_arc_check_value),
          UNIT(test_chunked_updates), UNIT(test_poll_timeout_rounding))
