/* lf_exec_scan (fap monitor's view of execAsyncByteIn): spans of good and
 * bad frames as stream offsets, reasons, a frame cut by DLE STX. */
#include "execasync/codec_internal.h"
#include "unit.h"

static const uint8_t GOOD[] = {0x10, 0x02, 0x05, 0x01, 0x41, 0x42, 0x43, 0x10, 0x03, 0xb9, 0xec};
static const uint8_t BADCRC[] = {0x10, 0x02, 0x05, 0x01, 0x41, 0x42, 0x43, 0x10, 0x03, 0xb9, 0xed};

static void test_spans(void)
{
    uint8_t s_[64];
    size_t n = 0;
    memcpy(s_ + n, "\x00\x01", 2); n += 2;
    memcpy(s_ + n, GOOD, sizeof GOOD); n += sizeof GOOD;
    s_[n++] = 0x55;
    memcpy(s_ + n, BADCRC, sizeof BADCRC); n += sizeof BADCRC;
    lf_exec_scan sc;
    lf_exec_scan_init(&sc);
    size_t used = lf_exec_scan_feed(&sc, s_, n);
    CHECK_EQ(used, 2 + sizeof GOOD);
    CHECK_EQ(sc.st.Status, EXEC_ASYNC_GOOD);
    CHECK_EQ(sc.rep_start, 2);
    CHECK_EQ(sc.rep_end, 2 + sizeof GOOD);
    CHECK_EQ(sc.st.Node, 5);
    CHECK_EQ(sc.st.Length, 3);
    CHECK(lf_exec_status_reason(EXEC_ASYNC_GOOD) == NULL);
    used += lf_exec_scan_feed(&sc, s_ + used, n - used);
    CHECK_EQ(used, n);
    CHECK_EQ(sc.st.Status, EXEC_ASYNC_BAD_CRC);
    CHECK_EQ(sc.rep_start, 3 + sizeof GOOD);
    CHECK_EQ(sc.rep_end, n);
    CHECK_EQ(strcmp(lf_exec_status_reason(sc.st.Status), "crc"), 0);
}

static void test_cut_by_stx(void)
{
    /* a frame cut short by DLE STX: FRAMING, span ends before the new DLE STX */
    const uint8_t cut[] = {0x10, 0x02, 0x05, 0x01, 0x41};
    uint8_t s_[64];
    size_t n = 0;
    memcpy(s_, cut, sizeof cut); n += sizeof cut;
    memcpy(s_ + n, GOOD, sizeof GOOD); n += sizeof GOOD;
    lf_exec_scan sc;
    lf_exec_scan_init(&sc);
    size_t used = lf_exec_scan_feed(&sc, s_, n);
    CHECK_EQ(sc.st.Status, EXEC_ASYNC_FRAMING);
    CHECK_EQ(sc.rep_start, 0);
    CHECK_EQ(sc.rep_end, sizeof cut);
    CHECK_EQ(strcmp(lf_exec_status_reason(sc.st.Status), "framing"), 0);
    used += lf_exec_scan_feed(&sc, s_ + used, n - used);
    CHECK_EQ(used, n);
    CHECK_EQ(sc.st.Status, EXEC_ASYNC_GOOD);
    CHECK_EQ(sc.rep_start, sizeof cut);
    CHECK_EQ(sc.rep_end, n);
    CHECK_EQ(strcmp(lf_exec_status_reason(EXEC_ASYNC_OVERFLOW), "length"), 0);
}

UNIT_MAIN(UNIT(test_spans), UNIT(test_cut_by_stx))
