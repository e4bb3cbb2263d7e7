/* exec_async_engine.h - exec async master and slave on a libfap port.
 *
 * Built on the frame functions of <exec_async.h> and the port layer of
 * <fap_port.h> (raw 8N1, RS-485 direction, echo suppression, turnaround).
 *
 * Master: execMasterTransact() polls one node and waits for its reply on the
 * caller's thread; on a timeout or a corrupted reply it sends the same frame
 * again with the same sequence number, up to `retries` times. Sequence
 * numbers are kept per node: 0 for the first message to a node, then
 * 1..255, 255 wraps to 1. execMasterBroadcast() sends on node 255 and waits
 * for nothing.
 *
 * Slave: execSlaveServe() waits for one request for its node (or a
 * broadcast), calls the handler in the same thread and sends the reply. A
 * repeated sequence number gets the last reply again, unchanged, without
 * calling the handler; sequence number 0 is always processed. Frames for
 * other nodes and corrupted frames are skipped. A frame that arrives while
 * the slave is answering (between the end of a request and the start of
 * its reply: handler time and turnaround delay) is dropped, not processed
 * and not answered (stats.rx_during_tx); the master's retry of it is then
 * processed. (A broadcast in that window is still processed: it is never
 * answered and never repeated.) During the reply's own transmission only a bus that echoes
 * can tell (echo suppression: FAP_PORT_ECOLLISION, stats.collisions).
 *
 * Return convention: 0 or a positive value on success, a negative errno or
 * a FAP_PORT_E* code on failure:
 *   -EINVAL      bad argument (node out of range, NULL where not allowed)
 *   -EMSGSIZE    payload longer than EXEC_ASYNC_MAX_DATA (255)
 *   -ETIMEDOUT   no reply after every attempt (last attempt timed out)
 *   -EBADMSG     no reply after every attempt (last attempt got a corrupt frame)
 *   -ENOBUFS     the reply is longer than the caller's buffer: the first
 *                reply_cap bytes are copied and *reply_len is the full length
 *   -ECANCELED   execSlaveStop() / execMasterStop() was called
 *   -EIO, -ENXIO ... the port failed (see fap_port_strerror)
 * Every function that sends returns the port's error unchanged.
 */
#ifndef EXEC_ASYNC_ENGINE_H
#define EXEC_ASYNC_ENGINE_H

#include <stdint.h>

#include "exec_async.h"
#include "fap_port.h"
#include "fap_trace.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- master ------------------------------------------------------------ */

typedef struct execMasterOptions {
    unsigned reply_timeout_us;  /* per attempt, from the end of our frame to the
                                   end of the reply; 0 = 100 ms. At 9600 baud a
                                   255-byte reply alone takes ~540 ms: raise it */
    unsigned retries;           /* extra attempts after the first; default 3 */
    int cancel_fd;              /* the open's external cancel: while the open
                                   runs (name lookup, connect, RFC 2217
                                   negotiation), this fd turning readable (an
                                   eventfd written from another thread, a
                                   signal handler) ends it with -ECANCELED.
                                   Watched only during the open; the caller
                                   keeps it open until the open returns.
                                   0 = none */
} execMasterOptions;

typedef struct execMasterStats {
    uint64_t transactions;   /* execMasterTransact/Begin calls past argument checks */
    uint64_t replies;        /* transactions that got their reply */
    uint64_t failures;       /* transactions that gave up (or execMasterAbort) */
    uint64_t retries;        /* frames sent again */
    uint64_t timeouts;       /* attempts that timed out */
    uint64_t corrupt;        /* frames with a bad CRC, framing error or overflow */
    uint64_t unexpected;     /* good frames that were not the awaited reply */
    uint64_t broadcasts;
    uint64_t tx_frames;
    uint64_t rx_frames;      /* every frame decoded, good or not */
} execMasterStats;

typedef struct execMaster execMaster;

void execMasterOptionsInit(execMasterOptions *o);
/* Open the port at path (port options NULL = fap_port_options_init defaults,
 * o NULL = execMasterOptionsInit defaults). *out is set only on success. */
int execMasterOpen(execMaster **out, const char *path, const fap_port_options *port,
                   const execMasterOptions *o);
/* Change the timeout (0 = default) and retries of an open master. */
int execMasterSetTimeout(execMaster *m, unsigned reply_timeout_us, unsigned retries);
/* Poll node (1..254) with req_len bytes and wait for its reply (0..255
 * bytes) into reply (reply_cap bytes; may be NULL if reply_cap is 0).
 * *reply_len (may be NULL) receives the reply length. Returns 0 or an error
 * above. Thread-safe: concurrent calls are serialised. */
int execMasterTransact(execMaster *m, byte node, const byte *req, word req_len,
                       byte *reply, word reply_cap, word *reply_len);
/* ---- master without blocking (for an event loop) -------------------------
 * The transaction of execMasterTransact split at its waits; execMasterTransact
 * is these two calls with a blocking wait on the port fd between steps, so
 * retries, sequence numbers, the trace hook and the stats are the same:
 *
 *   rc = execMasterBegin(m, node, req, len, &deadline);
 *   while (rc == 0 || rc == EXEC_MASTER_MORE) {
 *       wait until execMasterPort(m)'s fd (fap_port_fd) is readable or
 *       CLOCK_MONOTONIC reaches deadline;
 *       rc = execMasterStep(m, reply, cap, &reply_len, &deadline);
 *       if (rc == 0) break;                  // the reply is in
 *   }
 *
 * Begin: flush the input, encode req with the node's sequence number, send.
 * Returns 0 and *deadline_ns (CLOCK_MONOTONIC ns, may be NULL) of the first
 * attempt, or an error (the transaction is then over: counted as a failure,
 * the node restarts at SeqNo 0). -EBUSY: a transaction begun with
 * execMasterBegin is still in flight (one at a time per master); a blocking
 * execMasterTransact in another thread makes Begin wait for its end.
 * Step: read what is queued (never waits or sleeps), decode, and resend on
 * a corrupt reply or a passed deadline. Returns EXEC_MASTER_MORE with the
 * current attempt's deadline (it moves on a resend), 0 with the reply as
 * execMasterTransact, or an error of execMasterTransact; after 0 or an error
 * the transaction is over. -EINVAL when none is in flight.
 * Abort: end the transaction in flight (if any) as a failure (stats.failures,
 * next SeqNo 0: the slave may have processed it). For a cancelled wait.
 * execMasterTransact and execMasterBroadcast wait until a Begin/Step
 * transaction is over. */
#define EXEC_MASTER_MORE 1
int execMasterBegin(execMaster *m, byte node, const byte *req, word req_len,
                    int64_t *deadline_ns);
int execMasterStep(execMaster *m, byte *reply, word reply_cap, word *reply_len,
                   int64_t *deadline_ns);
void execMasterAbort(execMaster *m);
/* Send data to every slave (node 255); nobody answers. */
int execMasterBroadcast(execMaster *m, const byte *data, word len);
/* The sequence number the next message to node (1..255) will carry. */
int execMasterNextSeq(execMaster *m, byte node);
/* Start again from 0 for every node (a restart, as the slaves see it). */
void execMasterResetSequence(execMaster *m);
void execMasterGetStats(execMaster *m, execMasterStats *out);
/* The underlying port (for fap_port_get_stats); owned by the master. */
fap_port *execMasterPort(execMaster *m);
void execMasterClose(execMaster *m);   /* NULL accepted */
/* Make the transaction in flight (its write or its wait for the reply) and
 * every later transaction and broadcast return -ECANCELED at once, so a
 * closer in another thread never waits out a timeout. Safe from any thread
 * and from a signal handler (one write to an eventfd). NULL accepted. */
void execMasterStop(execMaster *m);
/* Install (or with NULL remove) the wire trace hook (fap_trace.h): every
 * request sent and every frame received (replies, bad frames, partial
 * replies abandoned at a retry or at the end of the transaction), called
 * on the thread inside execMasterTransact/Broadcast. When this returns the
 * previous hook is not running. Not from inside the hook. */
void execMasterSetTrace(execMaster *m, fap_trace_fn fn, void *ctx);

/* ---- slave ------------------------------------------------------------- */

typedef struct execSlaveOptions {
    byte node;                  /* 1..254 */
    int cancel_fd;              /* the open's external cancel: while the open
                                   runs (name lookup, connect, RFC 2217
                                   negotiation), this fd turning readable (an
                                   eventfd written from another thread, a
                                   signal handler) ends it with -ECANCELED.
                                   Watched only during the open; the caller
                                   keeps it open until the open returns.
                                   0 = none */
} execSlaveOptions;

typedef struct execSlaveStats {
    uint64_t processed;      /* requests passed to the handler (not broadcasts) */
    uint64_t resent;         /* retries answered with the last reply */
    uint64_t broadcasts;     /* broadcasts passed to the handler */
    uint64_t replies;        /* reply frames sent (fresh and resent; a failed write
                                is counted too, and returned by execSlaveServe) */
    uint64_t no_reply;       /* handler chose not to answer */
    uint64_t ignored;        /* good frames for other nodes */
    uint64_t corrupt;        /* bad CRC, framing error or overflow */
    uint64_t rx_during_tx;   /* requests dropped: arrived while we were answering */
    uint64_t collisions;     /* our reply's echo came back altered (2-wire bus) */
    uint64_t rx_frames;
} execSlaveStats;

/* A request as the handler sees it. */
typedef struct execSlaveRequest {
    byte node;               /* our node, or EXEC_ASYNC_BROADCAST */
    byte seq;
    word len;
    const byte *data;
} execSlaveRequest;

/* Called by execSlaveServe in its caller's thread. Write the reply
 * (0..reply_cap = 255 bytes) into reply and return its length; return a
 * negative value to send no reply. The return value is ignored for a
 * broadcast. */
typedef int (*execSlaveHandler)(void *ctx, const execSlaveRequest *req,
                                byte *reply, word reply_cap);

typedef struct execSlave execSlave;

void execSlaveOptionsInit(execSlaveOptions *o);   /* node 1 */
/* The turnaround delay (quiet time before the slave answers) is the port's
 * turnaround_us option. */
int execSlaveOpen(execSlave **out, const char *path, const fap_port_options *port,
                  const execSlaveOptions *o, execSlaveHandler handler, void *ctx);
/* Wait up to timeout_ms (-1 = forever) for one request for this node and
 * handle it. Returns EXEC_SLAVE_PROCESSED, EXEC_SLAVE_RESENT,
 * EXEC_SLAVE_BROADCAST, 0 when the time ran out, or a negative error
 * (-EMSGSIZE: the handler returned more than 255; nothing was sent).
 * One thread at a time may serve a slave. */
#define EXEC_SLAVE_PROCESSED 1
#define EXEC_SLAVE_RESENT    2
#define EXEC_SLAVE_BROADCAST 3
int execSlaveServe(execSlave *s, int timeout_ms);
/* Make the current and every later execSlaveServe return -ECANCELED at once.
 * Safe from any thread (and from a signal handler: one write to an eventfd). */
void execSlaveStop(execSlave *s);
void execSlaveGetStats(execSlave *s, execSlaveStats *out);
fap_port *execSlavePort(execSlave *s);
/* Close; no thread may be inside execSlaveServe. NULL accepted. */
void execSlaveClose(execSlave *s);
/* The same for a slave: every frame heard (any node, good or bad) and
 * every reply sent, on the thread inside execSlaveServe. */
void execSlaveSetTrace(execSlave *s, fap_trace_fn fn, void *ctx);

#ifdef __cplusplus
}
#endif
#endif /* EXEC_ASYNC_ENGINE_H */
