/* Sans-I/O sequence-number logic of the exec async master and slave.
 * No fds, no threads: decoded frames, a clock value and results in,
 * decisions out. The I/O layers (master.c, slave.c) drive these. */
#ifndef LF_EXEC_SEQ_LOGIC_H
#define LF_EXEC_SEQ_LOGIC_H

#include <stddef.h>
#include <stdint.h>

#include "common/mono_clock.h"
#include "exec_async.h"

/* 0 at start-up, then 1..255, 255 wraps to 1 (0 means "start-up" to a slave). */
static inline uint8_t lf_exec_seq_next(uint8_t seq)
{
    return seq == 255 ? 1 : (uint8_t)(seq + 1);
}

/* ---- master: one transaction (poll + wait for the reply, with retries) ---- */

typedef enum lf_exec_mact {
    LF_EXEC_M_WAIT,   /* keep receiving until lf_exec_mtx.deadline */
    LF_EXEC_M_SEND,   /* (re)send the same frame, then wait */
    LF_EXEC_M_DONE,   /* the reply is in the decoder's buffer */
    LF_EXEC_M_FAIL    /* no attempt left; see last_error */
} lf_exec_mact;

/* What one frame did to a transaction, for statistics. */
typedef enum lf_exec_mevent {
    LF_EXEC_EV_NONE,
    LF_EXEC_EV_REPLY,      /* the awaited reply */
    LF_EXEC_EV_CORRUPT,    /* bad CRC, framing or overflow */
    LF_EXEC_EV_UNEXPECTED  /* a good frame from another node or with another seq */
} lf_exec_mevent;

typedef struct lf_exec_mtx {
    uint8_t node, seq;
    unsigned long long attempt;       /* attempts sent so far */
    unsigned long long max_attempts;  /* 1 + retries: wide, so UINT_MAX retries do not wrap */
    lf_ns timeout;           /* per attempt */
    lf_ns deadline;          /* of the current attempt */
    int last_error;          /* -ETIMEDOUT or -EBADMSG when failing */
    lf_exec_mevent event;    /* what the last on_frame saw */
} lf_exec_mtx;

/* Per-node sequence numbers: zero-filled = every node starts at 0. */
typedef struct lf_exec_mseq {
    uint8_t next[256];
} lf_exec_mseq;

/* A transaction to node with seq has ended. Success moves on (1..255);
 * failure restarts the node at 0: it may have missed any number of our
 * messages, so any other number could equal the one it last processed and
 * fetch a stale reply. 0 is always processed fresh. */
void lf_exec_mseq_finish(lf_exec_mseq *m, uint8_t node, uint8_t seq, int ok);

void lf_exec_mtx_start(lf_exec_mtx *t, uint8_t node, uint8_t seq,
                       unsigned retries, lf_ns timeout);
/* The caller has just sent the frame (start, or after LF_EXEC_M_SEND). */
void lf_exec_mtx_sent(lf_exec_mtx *t, lf_ns now);
/* A frame was decoded (execAsyncByteIn returned true). */
lf_exec_mact lf_exec_mtx_on_frame(lf_exec_mtx *t, const struct execAsyncStateDef *st);
/* Nothing (more) arrived: deadline check. */
lf_exec_mact lf_exec_mtx_on_time(lf_exec_mtx *t, lf_ns now);

/* ---- slave: what to do with a decoded frame ---- */

typedef enum lf_exec_sact {
    LF_EXEC_S_IGNORE,     /* not for us, or corrupt */
    LF_EXEC_S_PROCESS,    /* new request: run the handler, reply, then commit */
    LF_EXEC_S_RESEND,     /* retry of the last request: resend the last reply */
    LF_EXEC_S_BROADCAST,  /* process, never reply */
    LF_EXEC_S_WINDOW      /* arrived while we answered: drop (lf_exec_rwin) */
} lf_exec_sact;

typedef struct lf_exec_sseq {
    uint8_t node;          /* our node number, 1..254 */
    uint8_t have_last;     /* a request has been processed since start */
    uint8_t last_seq;
} lf_exec_sseq;

lf_exec_sact lf_exec_sseq_classify(const lf_exec_sseq *s, const struct execAsyncStateDef *st);
/* The request with this seq has been processed and answered. */
void lf_exec_sseq_commit(lf_exec_sseq *s, uint8_t seq);

/* ---- slave: the reply window ----
 * Our response phase runs from the end of a request to the end of our
 * reply. Every byte received before the reply starts (during the handler
 * and the turnaround delay, which the slave spends watching the line)
 * belongs to that window; a frame with a byte in the window is dropped:
 * not processed, not answered. A broadcast is the exception: never
 * answered and never repeated by the master, it is still processed.
 * Bytes that arrive during the write itself are the echo check's business
 * (FAP_PORT_ECOLLISION), not the window's. The slave keeps its received
 * bytes in one buffer; the window is a prefix of it. */
typedef struct lf_exec_rwin {
    size_t end;     /* buffer[0, end) arrived in the window */
    int taint;      /* the frame being decoded has a byte in the window */
} lf_exec_rwin;

/* The caller dropped the first n bytes of its buffer. */
void lf_exec_rwin_shift(lf_exec_rwin *w, size_t n);
/* Byte i of the buffer went through the decoder. done: it ended a frame
 * (execAsyncByteIn returned true); in_frame: the decoder is inside a frame
 * after it (a framing report may already be inside the next one). Returns
 * 1 when done and the frame it ended had a byte in the window, else 0. */
int lf_exec_rwin_byte(lf_exec_rwin *w, size_t i, int done, int in_frame);
/* lf_exec_sseq_classify, then the window rule: a tainted frame that would
 * be processed or answered is LF_EXEC_S_WINDOW instead. */
lf_exec_sact lf_exec_sseq_decide(const lf_exec_sseq *s, const struct execAsyncStateDef *st,
                                 int tainted);

#endif
