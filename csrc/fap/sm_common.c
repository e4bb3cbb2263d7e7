/* Helpers shared by the master and slave state machines. */
#include "fap/fap_sm.h"
#include <errno.h>

void lf_fap_timing_fill(lf_fap_timing *t)
{
    if (t->idc <= 0)
        t->idc = LF_FAP_DEFAULT_IDC;
    if (t->id_answer <= 0)
        t->id_answer = LF_FAP_DEFAULT_ID_ANSWER;
    if (t->data_done <= 0)
        t->data_done = LF_FAP_DEFAULT_DATA_DONE;
    if (t->send_budget <= 0)
        t->send_budget = LF_FAP_DEFAULT_BUDGET;
}

int lf_fap_outbox_put(lf_fap_outbox *o, unsigned msg, unsigned dst, unsigned src,
                      const uint8_t *data, size_t len)
{
    size_t n = lf_fap_encode(o->buf, sizeof o->buf, msg, dst, src, data, len);
    if (n == 0)
        return -EINVAL;
    o->len = n;
    o->msg = (uint8_t)msg;
    o->dst = (uint8_t)dst;
    return 0;
}

int lf_fap_next_data(lf_fap_outbox *o, const lf_fap_io *io, uint8_t *scratch, unsigned self,
                     lf_ns now, lf_ns budget_end, lf_fap_sm_counts *c)
{
    while (now < budget_end) {
        uint8_t dst;
        uint16_t len;
        if (!io->tx_pop || !io->tx_pop(io->ctx, &dst, scratch, &len))
            return 0;
        if (dst == self || dst > LF_FAP_MAX_ID ||
            lf_fap_outbox_put(o, LF_FAP_DATA, dst, self, scratch, len) != 0) {
            c->tx_dropped++;
            continue;
        }
        c->data_tx++;
        return 1;
    }
    c->budget_cutoffs++;
    return 0;
}
