/* When a polled slave's DATA_DONE can be complete: see reply_predict.h. */
#include "fap/reply_predict.h"
#include <string.h>

#define REPLY_LEN LF_FAP_OVERHEAD   /* DATA_DONE: a frame without data */

void lf_reply_predict_init(lf_reply_predict *p, unsigned baud, int device)
{
    memset(p, 0, sizeof *p);
    p->ct = device ? lf_char_time_ns(baud) : 0;
    for (unsigned id = 0; id <= LF_FAP_MAX_ID; id++)
        p->ta[id] = -1;
}

static int valid(const lf_reply_predict *p, unsigned id)
{
    return p->ct > 0 && id >= 1 && id <= LF_FAP_MAX_ID;
}

lf_ns lf_reply_predict_when(lf_reply_predict *p, unsigned id, lf_ns sent_end)
{
    if (!valid(p, id) || !p->paced || !p->tight[id] || p->data[id] || p->ta[id] < 0)
        return 0;
    if (++p->since_observe[id] >= LF_REPLY_PREDICT_OBSERVE_EVERY) {
        p->since_observe[id] = 0;
        return 0;
    }
    return sent_end + p->ta[id] + REPLY_LEN * p->ct;
}

void lf_reply_predict_observed(lf_reply_predict *p, unsigned id, lf_ns sent_end, lf_ns now)
{
    if (!valid(p, id))
        return;
    lf_ns wire = REPLY_LEN * p->ct;
    /* Sooner than 70 % of the reply's wire time after our frame's end: the
     * link runs faster than the baud (a pty, a faster bus): no prediction. */
    p->paced = now - sent_end >= wire * 7 / 10;
    if (!p->paced) {
        p->ta[id] = -1;
        p->tight[id] = 0;
        p->obs_n[id] = 0;
        return;
    }
    lf_ns ta = now - sent_end - wire;
    if (ta < 0)
        ta = 0;
    if (p->tight[id]) {
        if (p->ta[id] < 0 || ta < p->ta[id])
            p->ta[id] = ta;
        return;
    }
    /* not yet tight: a run of observations within a character time of
     * each other starts the predictions at their smallest */
    if (p->obs_n[id] == 0 || ta < p->obs_lo[id])
        p->obs_lo[id] = ta;
    if (p->obs_n[id] == 0 || ta > p->obs_hi[id])
        p->obs_hi[id] = ta;
    if (++p->obs_n[id] < LF_REPLY_PREDICT_TIGHT_N)
        return;
    p->obs_n[id] = 0;
    if (p->obs_hi[id] - p->obs_lo[id] > p->ct)
        return;                     /* spread out: another run */
    p->tight[id] = 1;
    p->ta[id] = p->obs_lo[id];
    p->late[id] = 0;
    p->downs[id] = 0;
}

void lf_reply_predict_turn(lf_reply_predict *p, unsigned id, int sent_data)
{
    if (valid(p, id))
        p->data[id] = sent_data != 0;
}

void lf_reply_predict_outcome(lf_reply_predict *p, unsigned id, size_t missing)
{
    if (!valid(p, id) || !p->tight[id] || p->ta[id] < 0)
        return;
    /* The step: an eighth of a character time (the master's lateness on a
     * complete read is about the step: small), or 1/16 of the estimate
     * when that is more (a turnaround of many character times, 1 Mbaud,
     * or a slave that slowed down, is followed in tens of polls). Up and
     * down alike: about one read in two finds the last byte missing. */
    lf_ns step = p->ct / 8;
    if (p->ta[id] / 16 > step)
        step = p->ta[id] / 16;
    p->late[id] = (uint8_t)(p->late[id] << 1 | (missing > 1));
    if (__builtin_popcount(p->late[id]) >= LF_REPLY_PREDICT_WIDE_OF_8) {
        /* spread wider than a character time: observe until it is tight */
        p->tight[id] = 0;
        p->obs_n[id] = 0;
        p->ta[id] = -1;
        return;
    }
    if (missing) {
        p->downs[id] = 0;
        p->ta[id] += step;
        return;
    }
    if (p->ta[id] == 0)
        p->paced = 0;               /* complete even at no turnaround: observe again */
    /* from the third complete read in a row the estimate may be late by
     * much (its first observation carried a wake-up's latency): double the
     * step each time, up to 8x (two in a row are common around the reply's end) */
    p->downs[id]++;
    unsigned k = p->downs[id] < 3 ? 0 : p->downs[id] - 2 < 3 ? p->downs[id] - 2 : 3;
    step <<= k;
    p->ta[id] = p->ta[id] > step ? p->ta[id] - step : 0;
}
