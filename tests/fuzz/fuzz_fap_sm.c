/* FAP master and slave state machines fed arbitrary frames, events (slave
 * list changes, queued data, transmissions done) and clock steps.
 * Properties: the outbox always holds exactly one valid frame from this
 * node (it decodes, CRC and all, to one frame with our source ID); the
 * master only queries / polls listed slaves and never sends DATA to
 * itself or past ID 31; deadlines never lie in the past of a finished
 * timer call. */
#include "fuzz_util.h"
#include "fap/codec.h"
#include "fap/sm_master.h"
#include "fap/sm_slave.h"

typedef struct q { uint8_t dst; uint16_t len; uint8_t data[LF_FAP_MAX_DATA]; } q;
static q txq[16];
static int tx_head, tx_count;

static int tx_pop(void *ctx, uint8_t *dst, uint8_t *data, uint16_t *len)
{
    (void)ctx;
    if (!tx_count)
        return 0;
    *dst = txq[tx_head].dst;
    *len = txq[tx_head].len;
    memcpy(data, txq[tx_head].data, *len);
    tx_head = (tx_head + 1) % 16;
    tx_count--;
    return 1;
}
static void deliver(void *ctx, uint8_t src, const uint8_t *d, uint16_t len, lf_ns now)
{
    (void)ctx; (void)src; (void)now;
    PROPERTY(len >= 1 && len <= LF_FAP_MAX_DATA && d);
}
static void event(void *ctx, int type, unsigned id, lf_ns now)
{
    (void)ctx; (void)now;
    PROPERTY(type >= 1 && type <= 4 && id <= LF_FAP_MAX_ID);
}

typedef struct seen { int n; lf_fap_frame f; uint8_t data[LF_FAP_MAX_DATA]; } seen;
static void on_frame(void *ctx, const lf_fap_frame *f, lf_ns now)
{
    (void)now;
    seen *s = ctx;
    if (s->n++ == 0) {
        s->f = *f;
        memcpy(s->data, f->data, f->len);
    }
}

static lf_fap_master m;
static lf_fap_slave sl;
static lf_fap_decoder dec;

static void check_outbox(const lf_fap_outbox *o, unsigned self, int is_master)
{
    if (!o->len)
        return;
    seen s = {0};
    lf_fap_decoder_init(&dec, 1000);
    lf_fap_decoder_feed(&dec, o->buf, o->len, 1, on_frame, &s);
    PROPERTY(s.n == 1);
    PROPERTY(s.f.src == self && s.f.msg == o->msg && s.f.dst == o->dst);
    if (s.f.msg == LF_FAP_DATA)
        PROPERTY(s.f.dst != self && s.f.dst <= LF_FAP_MAX_ID);
    if (is_master && (s.f.msg == LF_FAP_QUERY_ID || s.f.msg == LF_FAP_SEND_DATA))
        PROPERTY(s.f.dst >= 1 && s.f.dst <= LF_FAP_MAX_ID);
    if (!is_master)
        PROPERTY(s.f.msg == LF_FAP_DATA || s.f.msg == LF_FAP_DATA_DONE || s.f.msg == LF_FAP_ID);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fz f = {data, size};
    int is_master = fz_u8(&f) & 1;
    unsigned self = is_master ? 0 : 1 + fz_u8(&f) % LF_FAP_MAX_ID;
    lf_fap_timing t = {
        .idc = (lf_ns)(fz_u8(&f) + 1) * 1000000, .id_answer = (lf_ns)(fz_u8(&f) + 1) * 100000,
        .data_done = (lf_ns)(fz_u8(&f) + 1) * 100000, .send_budget = (lf_ns)(fz_u8(&f) + 1) * 100000,
    };
    lf_fap_io io = { .tx_pop = tx_pop, .deliver = deliver, .event = event };
    tx_head = tx_count = 0;
    lf_ns now = 1000;
    if (is_master)
        lf_fap_master_init(&m, &t, &io, now);
    else
        lf_fap_slave_init(&sl, self, &t, &io);
    unsigned steps = 0;
    while (fz_more(&f) && steps++ < 4096) {
        uint8_t op = fz_u8(&f);
        switch (op % 6) {
        case 0: {                                    /* a frame from the bus */
            uint8_t msg = fz_u8(&f) % 5;
            lf_fap_frame fr = { .msg = msg, .dst = fz_u8(&f), .src = fz_u8(&f) };
            if (op & 0x80) {                         /* mostly plausible IDs */
                fr.dst %= 32;
                fr.src %= 32;
            }
            const uint8_t *d = NULL;
            uint8_t one = 0;
            if (msg == LF_FAP_DATA) {
                fr.len = (uint16_t)fz_bytes(&f, 1 + fz_u8(&f) % 32, &d);
                if (!fr.len) {
                    d = &one;
                    fr.len = 1;
                }
            }
            fr.data = d;
            if (is_master)
                lf_fap_master_on_frame(&m, &fr, now);
            else
                lf_fap_slave_on_frame(&sl, &fr, now);
            break;
        }
        case 1: {                                    /* the clock moves */
            uint32_t step = fz_u32(&f);
            now += (op & 0x80) ? (lf_ns)step * 1000 : (lf_ns)step;
            lf_ns dl = is_master ? lf_fap_master_deadline(&m) : lf_fap_slave_deadline(&sl);
            if (is_master && now >= dl)
                lf_fap_master_on_timer(&m, now);
            break;
        }
        case 2:                                      /* the outbox frame went out */
            if (is_master && m.out.len)
                lf_fap_master_sent(&m, now);
            else if (!is_master && sl.out.len)
                lf_fap_slave_sent(&sl, now);
            break;
        case 3:
            if (is_master) {
                unsigned id = fz_u8(&f) % 40;
                if (op & 0x40)
                    lf_fap_master_remove(&m, id, now);
                else
                    lf_fap_master_add(&m, id, now);
            }
            break;
        case 4:                                      /* the application queues data */
            if (tx_count < 16) {
                q *e = &txq[(tx_head + tx_count) % 16];
                e->dst = fz_u8(&f) % 40;
                const uint8_t *d;
                e->len = (uint16_t)fz_bytes(&f, 1 + fz_u8(&f) % 16, &d);
                if (!e->len)
                    break;
                memcpy(e->data, d, e->len);
                tx_count++;
                if (is_master)
                    lf_fap_master_tx_queued(&m, now);
            }
            break;
        default:
            break;
        }
        check_outbox(is_master ? &m.out : &sl.out, self, is_master);
        if (is_master && m.out.len && (m.out.msg == LF_FAP_QUERY_ID || m.out.msg == LF_FAP_SEND_DATA))
            PROPERTY(m.listed >> m.out.dst & 1u || m.cur == m.out.dst);
    }
    return 0;
}
