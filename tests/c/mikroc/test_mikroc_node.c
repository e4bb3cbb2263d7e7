/* mikroC RS-485 master/slave nodes without I/O: the vendor buffers, the
 * address and broadcast rules, the error flag, and the vendor routines fed
 * byte by byte. */
#include <errno.h>

#include "mikroc_rs485.h"
#include "mikroc_vectors.h"
#include "unit.h"

static mv_vector vec[MV_MAX];
static size_t nvec;

static void feed_ctx(mikrocRS485_ctx *c, char *buf, const uint8_t *p, size_t n)
{
    for (size_t i = 0; i < n; i++)
        mikrocRS485_CtxReceiveByte(c, buf, p[i]);
}

static size_t frame_of(uint8_t *out, const char *data, unsigned len, uint8_t addr, int master)
{
    int n = mikrocRS485_Encode(out, (const uint8_t *)data, len, addr, master);
    return n > 0 ? (size_t)n : 0;
}

static int ready(const char *b) { return (uint8_t)b[MIKROC_RS485_IDX_READY] == 255; }
static int error(const char *b) { return (uint8_t)b[MIKROC_RS485_IDX_ERROR] == 255; }

/* Each valid vector reaches the node it is addressed to, with the right
 * buffer contents: master frames a slave at that address, slave frames the
 * master (which records the sender). */
static void test_vectors_fill_buffers(void)
{
    for (size_t i = 0; i < nvec; i++) {
        if (!vec[i].valid)
            continue;
        mikrocRS485_ctx c;
        char buf[8];
        memset(buf, 0x5A, sizeof buf);
        buf[4] = buf[5] = 0;
        if (vec[i].master)
            mikrocRS485_CtxInitSlave(&c, vec[i].address == 50 ? 7 : (uint8_t)vec[i].address);
        else
            mikrocRS485_CtxInitMaster(&c);
        feed_ctx(&c, buf, vec[i].frame, vec[i].frame_len);
        CHECK(ready(buf));
        CHECK(!error(buf));
        CHECK_EQ(buf[3], vec[i].data_len);
        CHECK_MEM(buf, vec[i].data, vec[i].data_len);
        for (size_t k = vec[i].data_len; k < 3; k++)
            CHECK_EQ(buf[k], 0);            /* unused data bytes zeroed */
        if (vec[i].master)
            CHECK_EQ((uint8_t)buf[6], 0x5A); /* slave buffer is 6 bytes: untouched */
        else
            CHECK_EQ((uint8_t)buf[6], vec[i].address);
        CHECK_EQ((uint8_t)buf[7], 0x5A);
    }
}

/* Invalid vectors: the addressed slave gets the error flag, never ready;
 * every other slave gets nothing. */
static void test_vectors_invalid_set_error(void)
{
    for (size_t i = 0; i < nvec; i++) {
        if (vec[i].valid)
            continue;
        uint8_t addr = vec[i].frame[1];
        mikrocRS485_ctx c;
        char buf[6] = {0};
        mikrocRS485_CtxInitSlave(&c, addr);
        feed_ctx(&c, buf, vec[i].frame, vec[i].frame_len);
        CHECK(error(buf));
        CHECK(!ready(buf));
        mikrocRS485_stats st;
        mikrocRS485_CtxGetStats(&c, &st);
        CHECK(st.last_rx_error == MIKROC_RS485_ECRC || st.last_rx_error == MIKROC_RS485_EFORMAT);

        char other[6] = {0};
        mikrocRS485_CtxInitSlave(&c, (uint8_t)(addr + 1));
        feed_ctx(&c, other, vec[i].frame, vec[i].frame_len);
        CHECK(!error(other));
        CHECK(!ready(other));
        mikrocRS485_CtxGetStats(&c, &st);
        CHECK_EQ(st.damaged, 1);
        CHECK_EQ(st.errors, 0);
    }
}

static void test_broadcast_rules(void)
{
    uint8_t fr[8];
    size_t n = frame_of(fr, "\x11\x22", 2, MIKROC_RS485_BROADCAST, 1);
    for (unsigned a = 0; a < 256; a++) {
        mikrocRS485_ctx c;
        char buf[6] = {0};
        mikrocRS485_CtxInitSlave(&c, (uint8_t)a);
        feed_ctx(&c, buf, fr, n);
        int expect = a != 150 && a != 169;
        if (ready(buf) != expect)
            fprintf(stderr, "  slave %u: ready=%d\n", a, ready(buf));
        CHECK_EQ(ready(buf), expect);
        CHECK(!error(buf));
        if (expect)
            CHECK_MEM(buf, "\x11\x22\x00\x02", 4);
    }
    /* slaves at 150 and 169 still receive their own address */
    static const uint8_t own[] = {150, 169};
    for (int k = 0; k < 2; k++) {
        mikrocRS485_ctx c;
        char buf[6] = {0};
        mikrocRS485_CtxInitSlave(&c, own[k]);
        n = frame_of(fr, "\x01", 1, own[k], 1);
        feed_ctx(&c, buf, fr, n);
        CHECK(ready(buf));
    }
}

static void test_other_address_never_ready(void)
{
    mikrocRS485_ctx c;
    char buf[6] = {0};
    mikrocRS485_CtxInitSlave(&c, 10);
    uint8_t fr[8];
    for (unsigned a = 0; a < 256; a++) {
        if (a == 10 || a == MIKROC_RS485_BROADCAST)
            continue;
        size_t n = frame_of(fr, "\x01\x02\x03", 3, (uint8_t)a, 1);
        feed_ctx(&c, buf, fr, n);
        /* damaged frames for others: not our error either */
        fr[3] ^= 0x40;
        feed_ctx(&c, buf, fr, n);
    }
    CHECK(!ready(buf));
    CHECK(!error(buf));
    mikrocRS485_stats st;
    mikrocRS485_CtxGetStats(&c, &st);
    CHECK_EQ(st.ignored, 254);
    CHECK_EQ(st.damaged, 254);
    CHECK_EQ(st.frames, 0);
}

/* Direction bit: a slave ignores replies of other slaves (even with its own
 * address, e.g. its own echo); a master ignores master frames. */
static void test_direction(void)
{
    mikrocRS485_ctx s, m;
    char sb[6] = {0}, mb[7] = {0};
    mikrocRS485_CtxInitSlave(&s, 5);
    mikrocRS485_CtxInitMaster(&m);
    uint8_t fr[8];
    size_t n = frame_of(fr, "\x01", 1, 5, 0);   /* slave 5 replies */
    feed_ctx(&s, sb, fr, n);
    CHECK(!ready(sb));
    feed_ctx(&m, mb, fr, n);
    CHECK(ready(mb));
    CHECK_EQ(mb[6], 5);
    mb[4] = 0;
    n = frame_of(fr, "\x01", 1, 5, 1);          /* master to 5 */
    feed_ctx(&m, mb, fr, n);
    CHECK(!ready(mb));
    feed_ctx(&s, sb, fr, n);
    CHECK(ready(sb));
    /* a damaged slave reply with our address is not our error */
    sb[4] = 0;
    n = frame_of(fr, "\x01", 1, 5, 0);
    fr[3] ^= 0x10;
    feed_ctx(&s, sb, fr, n);
    CHECK(!error(sb));
    feed_ctx(&m, mb, fr, n);                      /* but the master's */
    CHECK(error(mb));
}

/* Flags are set by the library and cleared only by the application; a
 * frame arriving while ready is still set is not stored (overrun). */
static void test_flags_and_overrun(void)
{
    mikrocRS485_ctx c;
    char buf[6] = {0};
    mikrocRS485_CtxInitSlave(&c, 3);
    uint8_t fr[8];
    size_t n = frame_of(fr, "\xAA", 1, 3, 1);
    feed_ctx(&c, buf, fr, n);
    CHECK(ready(buf));
    n = frame_of(fr, "\xBB\xCC", 2, 3, 1);
    feed_ctx(&c, buf, fr, n);
    CHECK(ready(buf));
    CHECK(error(buf));
    CHECK_EQ((uint8_t)buf[0], 0xAA);   /* the unread message is kept */
    CHECK_EQ(buf[3], 1);
    mikrocRS485_stats st;
    mikrocRS485_CtxGetStats(&c, &st);
    CHECK_EQ(st.overruns, 1);
    CHECK_EQ(st.last_rx_error, MIKROC_RS485_EOVERRUN);
    /* application clears ready only: next frame stored, error stays */
    buf[4] = 0;
    feed_ctx(&c, buf, fr, n);
    CHECK(ready(buf));
    CHECK(error(buf));
    CHECK_EQ((uint8_t)buf[1], 0xCC);
    CHECK_EQ(buf[3], 2);
}

/* A frame cut off by the next frame's start byte: error for its target,
 * and the next frame still arrives. */
static void test_cut_frame_then_next(void)
{
    mikrocRS485_ctx c;
    char buf[6] = {0};
    mikrocRS485_CtxInitSlave(&c, 160);
    uint8_t fr[8];
    size_t n = frame_of(fr, "\x01\x02\x03", 3, 160, 1);
    feed_ctx(&c, buf, fr, 4);            /* start, address, DATALEN, DATA1 */
    feed_ctx(&c, buf, fr, n);
    CHECK(error(buf));
    CHECK(ready(buf));
    CHECK_MEM(buf, "\x01\x02\x03\x03", 4);
    mikrocRS485_stats st;
    mikrocRS485_CtxGetStats(&c, &st);
    CHECK_EQ(st.last_rx_error, MIKROC_RS485_EABORT);
}

/* Slave address 50 is an ordinary address that also is the broadcast one. */
static void test_slave_at_50(void)
{
    mikrocRS485_ctx c;
    char buf[6] = {0};
    mikrocRS485_CtxInitSlave(&c, 50);
    uint8_t fr[8];
    size_t n = frame_of(fr, "\x07", 1, 50, 1);
    feed_ctx(&c, buf, fr, n);
    CHECK(ready(buf));
    CHECK_EQ(buf[0], 7);
}

static void test_uninitialised_context_ignores(void)
{
    mikrocRS485_ctx c;
    memset(&c, 0, sizeof c);
    char buf[7] = {0};
    uint8_t fr[8];
    size_t n = frame_of(fr, "\x07", 1, 1, 0);
    feed_ctx(&c, buf, fr, n);
    CHECK(!ready(buf));
    CHECK_EQ(mikrocRS485_CtxSend(&c, "\x01", 1, 1), -EPERM);
    CHECK_EQ(mikrocRS485_CtxPoll(&c, buf, 0), -EPERM);
}

/* The vendor routines: two global contexts, fed by the host helpers. */
static void test_vendor_routines_fed_bytewise(void)
{
    char mbuf[7] = {0}, sbuf[6] = {0};
    RS485Master_Init();
    RS485Slave_Init(0x12);
    uint8_t fr[8];
    size_t n = frame_of(fr, "\x01\x02\x03", 3, 0x12, 1);
    for (size_t i = 0; i < n; i++) {
        mikrocRS485Slave_ReceiveByte(sbuf, fr[i]);
        mikrocRS485Master_ReceiveByte(mbuf, fr[i]);   /* master ignores it */
    }
    CHECK(ready(sbuf));
    CHECK_MEM(sbuf, "\x01\x02\x03\x03", 4);
    CHECK(!ready(mbuf));
    n = frame_of(fr, "\x96", 1, 0x12, 0);            /* the reply */
    for (size_t i = 0; i < n; i++)
        mikrocRS485Master_ReceiveByte(mbuf, fr[i]);
    CHECK(ready(mbuf));
    CHECK_EQ((uint8_t)mbuf[0], 0x96);
    CHECK_EQ(mbuf[3], 1);
    CHECK_EQ(mbuf[6], 0x12);

    /* nothing bound: Receive is a no-op, Send records -ENOTCONN */
    mikrocRS485_Bind(NULL);
    char before[7];
    memcpy(before, mbuf, sizeof mbuf);
    RS485Master_Receive(mbuf);
    CHECK_MEM(before, mbuf, sizeof mbuf);
    RS485Master_Send(mbuf, 1, 0x12);
    CHECK_EQ(mikrocRS485_LastSendError(1), -ENOTCONN);
    /* datalen > 3 is rejected before anything else */
    RS485Slave_Send(sbuf, 4);
    CHECK_EQ(mikrocRS485_LastSendError(0), -EINVAL);
    RS485Master_Send(mbuf, (char)200, 1);
    CHECK_EQ(mikrocRS485_LastSendError(1), -EINVAL);
    CHECK_EQ(mikrocRS485_Poll(mbuf, 1, 0), -ENOTCONN);
    mikrocRS485_stats st;
    mikrocRS485_GetStats(0, &st);
    CHECK_EQ(st.frames, 1);
    CHECK_EQ(mikrocRS485_LastRxError(0), 0);
}

int main(void)
{
    nvec = mv_load(vec, MV_MAX);
    static const unit_test tests[] = {
        UNIT(test_vectors_fill_buffers),
        UNIT(test_vectors_invalid_set_error),
        UNIT(test_broadcast_rules),
        UNIT(test_other_address_never_ready),
        UNIT(test_direction),
        UNIT(test_flags_and_overrun),
        UNIT(test_cut_frame_then_next),
        UNIT(test_slave_at_50),
        UNIT(test_uninitialised_context_ignores),
        UNIT(test_vendor_routines_fed_bytewise),
    };
    return unit_run(tests, sizeof tests / sizeof tests[0]);
}
