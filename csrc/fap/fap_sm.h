/* What the FAP master and slave state machines share: the timing rules,
 * the callbacks through which they pull queued user data and push
 * deliveries and events, and the one-frame outbox.
 *
 * Protocol between a state machine and whoever drives it (the engine
 * thread, or a unit test with a fake clock):
 *   1. call an input (frame received, timer, tx queued, slave added...)
 *      with the current time;
 *   2. while the outbox holds a frame: transmit it, then call *_sent(now)
 *      with the time the transmission ended (reply windows start there);
 *   3. sleep until *_deadline() or the next input, whichever comes first.
 * No fds, threads or clocks inside. */
#ifndef LF_FAP_SM_H
#define LF_FAP_SM_H
#include <stdint.h>
#include "common/mono_clock.h"
#include "fap/codec.h"

typedef struct lf_fap_timing {
    lf_ns idc;          /* ID cycle period while a slave is inactive (15 s) */
    lf_ns id_answer;    /* QUERY_ID -> ID answer window (1 s) */
    lf_ns data_done;    /* SEND_DATA -> DATA_DONE limit (15 s) */
    lf_ns send_budget;  /* a node's sending time per turn (10 s) */
} lf_fap_timing;

#define LF_FAP_DEFAULT_IDC        (15 * LF_NS_PER_S)
#define LF_FAP_DEFAULT_ID_ANSWER  (1 * LF_NS_PER_S)
#define LF_FAP_DEFAULT_DATA_DONE  (15 * LF_NS_PER_S)
#define LF_FAP_DEFAULT_BUDGET     (10 * LF_NS_PER_S)

/* Zero fields take the defaults above. */
void lf_fap_timing_fill(lf_fap_timing *t);

enum lf_fap_event {
    LF_FAP_EV_SLAVE_ACTIVE = 1,    /* master: slave answered QUERY_ID */
    LF_FAP_EV_SLAVE_INACTIVE = 2,  /* master: active slave missed DATA_DONE */
    LF_FAP_EV_ID_TIMEOUT = 3,      /* master: slave did not answer QUERY_ID (stays inactive) */
    LF_FAP_EV_QUERIED = 4,         /* slave: master queried our ID (we answered) */
};

typedef struct lf_fap_io {
    void *ctx;
    /* Pop the oldest queued user frame: fill *dst, data (room for 1024) and
     * *len, return 1; return 0 when the queue is empty. */
    int (*tx_pop)(void *ctx, uint8_t *dst, uint8_t *data, uint16_t *len);
    /* DATA addressed to this node. */
    void (*deliver)(void *ctx, uint8_t src, const uint8_t *data, uint16_t len, lf_ns now);
    /* State changes (enum lf_fap_event). */
    void (*event)(void *ctx, int type, unsigned id, lf_ns now);
} lf_fap_io;

/* Protocol counters kept by the state machines. */
typedef struct lf_fap_sm_counts {
    uint64_t cycles;             /* master: completed data cycles */
    uint64_t id_cycles;          /* master: completed ID cycles */
    uint64_t polls;              /* SEND_DATA answered by DATA_DONE (slave: turns taken) */
    uint64_t id_timeouts;        /* master: QUERY_ID unanswered */
    uint64_t data_done_timeouts; /* master: DATA_DONE missing */
    uint64_t data_tx;            /* DATA frames sent */
    uint64_t data_rx;            /* DATA frames delivered to this node */
    uint64_t tx_dropped;         /* queued frames with an impossible destination */
    uint64_t unexpected;         /* valid frames that fit no state (late answers...) */
    uint64_t budget_cutoffs;     /* turns ended by the send budget with data left */
    uint64_t tx_to_inactive;     /* master: DATA sent to a slave not active at the time */
    uint64_t tx_unconfirmed;     /* master: DATA sent to a slave that then missed DATA_DONE */
} lf_fap_sm_counts;

/* The single frame waiting to be transmitted. */
typedef struct lf_fap_outbox {
    uint8_t buf[LF_FAP_MAX_FRAME];
    size_t  len;                 /* 0 = empty */
    uint8_t msg, dst;
} lf_fap_outbox;

int lf_fap_outbox_put(lf_fap_outbox *o, unsigned msg, unsigned dst, unsigned src,
                      const uint8_t *data, size_t len);

/* The send-budget rule of a node's turn (master slot or slave turn): put
 * the next queued DATA from node `self` in the outbox while now is before
 * budget_end. 1: a frame is in; 0: the queue is empty, or the budget is
 * spent (c->budget_cutoffs). A frame to `self` or past ID 31 is dropped
 * (c->tx_dropped) and the next one tried. scratch holds 1024 bytes. */
int lf_fap_next_data(lf_fap_outbox *o, const lf_fap_io *io, uint8_t *scratch, unsigned self,
                     lf_ns now, lf_ns budget_end, lf_fap_sm_counts *c);
#endif
