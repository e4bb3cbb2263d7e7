/* Sans-I/O sequence logic with a fake clock: the settled numbering rule,
 * master retries (timeout, CRC error, stray frames) and the slave's
 * process / resend / ignore decisions, and its reply-window rule. */
#include <errno.h>
#include <limits.h>

#include "execasync/codec_internal.h"
#include "execasync/sm_seq.h"
#include "unit.h"

static struct execAsyncStateDef frame(byte status, byte node, byte seq)
{
    struct execAsyncStateDef st;
    memset(&st, 0, sizeof st);
    st.Status = status;
    st.Node = node;
    st.SeqNo = seq;
    return st;
}

static void test_numbering_rule(void)
{
    /* the vectors' "sequence": 0 1 2 ... 254 255 1 2 */
    lf_exec_mseq m;
    memset(&m, 0, sizeof m);
    CHECK_EQ(m.next[7], 0);
    uint8_t s = 0;
    unsigned seen = 0;
    for (int i = 0; i < 600; i++) {
        uint8_t n = lf_exec_seq_next(s);
        CHECK(n != 0);
        CHECK(n == (s == 255 ? 1 : s + 1));
        s = n;
        seen++;
    }
    CHECK_EQ(lf_exec_seq_next(0), 1);
    CHECK_EQ(lf_exec_seq_next(254), 255);
    CHECK_EQ(lf_exec_seq_next(255), 1);
    CHECK_EQ(seen, 600);
}

static void test_master_reply_first_time(void)
{
    lf_exec_mtx t;
    lf_exec_mtx_start(&t, 3, 0, 2, 5 * LF_NS_PER_MS);
    lf_exec_mtx_sent(&t, 1000);
    CHECK_EQ(lf_exec_mtx_on_time(&t, 1000 + 4 * LF_NS_PER_MS), LF_EXEC_M_WAIT);
    struct execAsyncStateDef st = frame(EXEC_ASYNC_GOOD, 3, 0);
    CHECK_EQ(lf_exec_mtx_on_frame(&t, &st), LF_EXEC_M_DONE);
    CHECK_EQ(t.event, LF_EXEC_EV_REPLY);
    CHECK_EQ(t.attempt, 1);
}

static void test_master_timeout_retries_then_fails(void)
{
    lf_exec_mtx t;
    lf_exec_mtx_start(&t, 3, 9, 2, 5 * LF_NS_PER_MS);
    lf_ns now = 0;
    lf_exec_mtx_sent(&t, now);
    for (int attempt = 1; attempt <= 2; attempt++) {
        now += 5 * LF_NS_PER_MS;
        CHECK_EQ(lf_exec_mtx_on_time(&t, now), LF_EXEC_M_SEND);
        CHECK_EQ(t.seq, 9);                   /* same seq on every attempt */
        lf_exec_mtx_sent(&t, now);
    }
    now += 5 * LF_NS_PER_MS;
    CHECK_EQ(lf_exec_mtx_on_time(&t, now), LF_EXEC_M_FAIL);
    CHECK_EQ(t.last_error, -ETIMEDOUT);
    CHECK_EQ(t.attempt, 3);
}

static void test_master_crc_error_retries_at_once(void)
{
    lf_exec_mtx t;
    lf_exec_mtx_start(&t, 3, 9, 1, 5 * LF_NS_PER_MS);
    lf_exec_mtx_sent(&t, 0);
    struct execAsyncStateDef bad = frame(EXEC_ASYNC_BAD_CRC, 3, 9);
    CHECK_EQ(lf_exec_mtx_on_frame(&t, &bad), LF_EXEC_M_SEND);
    CHECK_EQ(t.event, LF_EXEC_EV_CORRUPT);
    lf_exec_mtx_sent(&t, 1);
    struct execAsyncStateDef framing = frame(EXEC_ASYNC_FRAMING, 0, 0);
    CHECK_EQ(lf_exec_mtx_on_frame(&t, &framing), LF_EXEC_M_FAIL);
    CHECK_EQ(t.last_error, -EBADMSG);
}

static void test_master_ignores_stray_frames(void)
{
    lf_exec_mtx t;
    lf_exec_mtx_start(&t, 3, 9, 0, 5 * LF_NS_PER_MS);
    lf_exec_mtx_sent(&t, 0);
    struct execAsyncStateDef other_node = frame(EXEC_ASYNC_GOOD, 4, 9);
    struct execAsyncStateDef old_seq = frame(EXEC_ASYNC_GOOD, 3, 8);
    struct execAsyncStateDef ours = frame(EXEC_ASYNC_GOOD, 3, 9);
    CHECK_EQ(lf_exec_mtx_on_frame(&t, &other_node), LF_EXEC_M_WAIT);
    CHECK_EQ(t.event, LF_EXEC_EV_UNEXPECTED);
    CHECK_EQ(lf_exec_mtx_on_frame(&t, &old_seq), LF_EXEC_M_WAIT);
    CHECK_EQ(lf_exec_mtx_on_frame(&t, &ours), LF_EXEC_M_DONE);
}

static void test_slave_rules(void)
{
    lf_exec_sseq s = {.node = 5};
    struct execAsyncStateDef f;
    f = frame(EXEC_ASYNC_GOOD, 5, 7);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_PROCESS);   /* first ever */
    lf_exec_sseq_commit(&s, 7);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_RESEND);    /* repeat = retry */
    f = frame(EXEC_ASYNC_GOOD, 5, 8);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_PROCESS);
    lf_exec_sseq_commit(&s, 8);
    f = frame(EXEC_ASYNC_GOOD, 5, 0);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_PROCESS);
    lf_exec_sseq_commit(&s, 0);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_PROCESS);   /* 0 always */
    f = frame(EXEC_ASYNC_GOOD, 6, 1);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_IGNORE);    /* other node */
    f = frame(EXEC_ASYNC_BAD_CRC, 5, 1);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_IGNORE);
    f = frame(EXEC_ASYNC_OVERFLOW, 5, 1);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_IGNORE);
    f = frame(EXEC_ASYNC_GOOD, 255, 0);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_BROADCAST);
    f = frame(EXEC_ASYNC_GOOD, 255, 0);
    CHECK_EQ(lf_exec_sseq_classify(&s, &f), LF_EXEC_S_BROADCAST); /* never "retried" */
}

/* Issue 12 defect 1: a pulled cable makes 254 transactions to node 4 fail;
 * the slave misses them all. With a counter that just moves on, the 255th
 * message carries the SeqNo the slave last processed, the slave takes it as
 * a retry and resends its old reply, which the master would accept. After
 * a failure the master must restart the node at 0, processed fresh. */
static void test_no_stale_reply_after_254_failures(void)
{
    lf_exec_mseq m;
    memset(&m, 0, sizeof m);
    lf_exec_sseq slave = {.node = 4};
    /* some successful traffic first: the slave processes 0, 1 .. 9 */
    for (int i = 0; i < 10; i++) {
        uint8_t seq = m.next[4];
        struct execAsyncStateDef f = frame(EXEC_ASYNC_GOOD, 4, seq);
        CHECK_EQ(lf_exec_sseq_classify(&slave, &f), LF_EXEC_S_PROCESS);
        lf_exec_sseq_commit(&slave, seq);
        lf_exec_mseq_finish(&m, 4, seq, 1);
    }
    uint8_t last_processed = slave.last_seq;
    CHECK_EQ(last_processed, 9);
    /* 254 failed transactions, every attempt lost on the wire */
    for (int i = 0; i < 254; i++) {
        uint8_t seq = m.next[4];
        lf_exec_mtx t;
        lf_exec_mtx_start(&t, 4, seq, 2, 5 * LF_NS_PER_MS);
        lf_ns now = 0;
        lf_exec_mact a;
        do {
            lf_exec_mtx_sent(&t, now);
            now += 5 * LF_NS_PER_MS;
        } while ((a = lf_exec_mtx_on_time(&t, now)) == LF_EXEC_M_SEND);
        CHECK_EQ(a, LF_EXEC_M_FAIL);
        lf_exec_mseq_finish(&m, 4, seq, 0);
        CHECK_EQ(m.next[4], 0);
    }
    /* the cable is back: the next message must not look like a retry */
    uint8_t seq = m.next[4];
    struct execAsyncStateDef f = frame(EXEC_ASYNC_GOOD, 4, seq);
    CHECK(seq != last_processed);
    CHECK_EQ(lf_exec_sseq_classify(&slave, &f), LF_EXEC_S_PROCESS);
    /* and the slave's old reply (seq 9) is not taken for the answer */
    lf_exec_mtx t;
    lf_exec_mtx_start(&t, 4, seq, 0, 5 * LF_NS_PER_MS);
    lf_exec_mtx_sent(&t, 0);
    struct execAsyncStateDef stale = frame(EXEC_ASYNC_GOOD, 4, last_processed);
    CHECK_EQ(lf_exec_mtx_on_frame(&t, &stale), LF_EXEC_M_WAIT);
    /* after the fresh 0 is answered, numbering goes on 1, 2 .. */
    lf_exec_sseq_commit(&slave, seq);
    lf_exec_mseq_finish(&m, 4, seq, 1);
    CHECK_EQ(m.next[4], 1);
    CHECK_EQ(m.next[5], 0);          /* other nodes untouched */
}

/* Issue 12 defect 5: retries = UINT_MAX must not wrap to one attempt. */
static void test_retries_uint_max_does_not_wrap(void)
{
    lf_exec_mtx t;
    lf_exec_mtx_start(&t, 3, 1, UINT_MAX, 1);
    lf_ns now = 0;
    for (int i = 0; i < 1000; i++) {
        lf_exec_mtx_sent(&t, now);
        now += 1;
        CHECK_EQ(lf_exec_mtx_on_time(&t, now), LF_EXEC_M_SEND);
    }
    CHECK_EQ(t.attempt, 1000);
}


/* The reply window, byte by byte: a frame with any byte in the window is
 * tainted, one wholly after it is not; taint survives a framing report
 * whose next frame started inside the window. */
static void test_reply_window_bytes(void)
{
    lf_exec_rwin w = {.end = 3};
    CHECK_EQ(lf_exec_rwin_byte(&w, 0, 0, 1), 0);   /* a frame starts in the window */
    CHECK_EQ(lf_exec_rwin_byte(&w, 4, 0, 1), 0);
    CHECK_EQ(lf_exec_rwin_byte(&w, 5, 1, 0), 1);   /* ...and ends after it: tainted */
    CHECK_EQ(lf_exec_rwin_byte(&w, 6, 0, 1), 0);
    CHECK_EQ(lf_exec_rwin_byte(&w, 7, 1, 0), 0);   /* the next one is clean */

    w = (lf_exec_rwin){.end = 2};
    CHECK_EQ(lf_exec_rwin_byte(&w, 0, 0, 0), 0);   /* noise while idle, in the window */
    CHECK_EQ(lf_exec_rwin_byte(&w, 1, 0, 0), 0);
    CHECK_EQ(lf_exec_rwin_byte(&w, 2, 0, 1), 0);   /* the frame starts after it */
    CHECK_EQ(lf_exec_rwin_byte(&w, 3, 1, 0), 0);

    w = (lf_exec_rwin){.end = 2};
    CHECK_EQ(lf_exec_rwin_byte(&w, 1, 1, 1), 1);   /* framing report, next frame begun */
    CHECK_EQ(lf_exec_rwin_byte(&w, 2, 0, 1), 0);
    CHECK_EQ(lf_exec_rwin_byte(&w, 3, 1, 0), 1);   /* that frame had a byte in the window */

    w = (lf_exec_rwin){.end = 5};
    lf_exec_rwin_shift(&w, 3);
    CHECK_EQ(w.end, 2);
    lf_exec_rwin_shift(&w, 7);
    CHECK_EQ(w.end, 0);
}

/* What a tainted frame does: a request or a retry is dropped, a broadcast
 * still processed, a frame for another node still ignored. */
static void test_reply_window_decisions(void)
{
    lf_exec_sseq s = {.node = 5};
    struct execAsyncStateDef f = frame(EXEC_ASYNC_GOOD, 5, 7);
    CHECK_EQ(lf_exec_sseq_decide(&s, &f, 0), LF_EXEC_S_PROCESS);
    CHECK_EQ(lf_exec_sseq_decide(&s, &f, 1), LF_EXEC_S_WINDOW);
    lf_exec_sseq_commit(&s, 7);
    CHECK_EQ(lf_exec_sseq_decide(&s, &f, 0), LF_EXEC_S_RESEND);
    CHECK_EQ(lf_exec_sseq_decide(&s, &f, 1), LF_EXEC_S_WINDOW);
    f = frame(EXEC_ASYNC_GOOD, EXEC_ASYNC_BROADCAST, 1);
    CHECK_EQ(lf_exec_sseq_decide(&s, &f, 1), LF_EXEC_S_BROADCAST);
    f = frame(EXEC_ASYNC_GOOD, 6, 1);
    CHECK_EQ(lf_exec_sseq_decide(&s, &f, 1), LF_EXEC_S_IGNORE);
    f = frame(EXEC_ASYNC_BAD_CRC, 5, 1);
    CHECK_EQ(lf_exec_sseq_decide(&s, &f, 1), LF_EXEC_S_IGNORE);
}

/* The same through the real decoder: two requests back to back, the
 * window ending inside the first; only the first is tainted. */
static void test_reply_window_decoder(void)
{
    byte wire[2 * EXEC_ASYNC_FRAME_SIZE(4)];
    byte data[4] = {1, 2, 3, 4};
    word n1 = execAsyncBufferOut(5, data, wire, 4, 1);
    word n2 = execAsyncBufferOut(5, data, wire + n1, 4, 2);
    struct execAsyncStateDef st;
    memset(&st, 0, sizeof st);
    byte buf[EXEC_ASYNC_MAX_DATA];
    lf_exec_rwin w = {.end = 2};
    lf_exec_sseq s = {.node = 5};
    int frames = 0;
    for (size_t i = 0; i < (size_t)(n1 + n2); i++) {
        int done = execAsyncByteIn(wire[i], &st, buf);
        int tainted = lf_exec_rwin_byte(&w, i, done, lf_exec_rx_in_frame(&st));
        if (!done)
            continue;
        frames++;
        CHECK_EQ(st.Status, EXEC_ASYNC_GOOD);
        CHECK_EQ(lf_exec_sseq_decide(&s, &st, tainted),
                 frames == 1 ? LF_EXEC_S_WINDOW : LF_EXEC_S_PROCESS);
    }
    CHECK_EQ(frames, 2);
}

UNIT_MAIN(UNIT(test_no_stale_reply_after_254_failures), UNIT(test_retries_uint_max_does_not_wrap),
          UNIT(test_numbering_rule), UNIT(test_master_reply_first_time),
          UNIT(test_master_timeout_retries_then_fails), UNIT(test_master_crc_error_retries_at_once),
          UNIT(test_master_ignores_stray_frames), UNIT(test_slave_rules),
          UNIT(test_reply_window_bytes), UNIT(test_reply_window_decisions),
          UNIT(test_reply_window_decoder))
