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
    if (!valid(p, id) || !p->paced || p->ta[id] < 0)
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
        return;
    }
    lf_ns ta = now - sent_end - wire;
    if (ta < 0)
        ta = 0;
    if (p->ta[id] < 0 || ta < p->ta[id])
        p->ta[id] = ta;
}

void lf_reply_predict_outcome(lf_reply_predict *p, unsigned id, size_t missing)
{
    if (!valid(p, id) || p->ta[id] < 0)
        return;
    /* The step: an eighth of a character time (the master's lateness on a
     * complete read is about the step: small), or 1/16 of the estimate
     * when that is more (a turnaround of many character times, 1 Mbaud,
     * or a slave that slowed down, is followed in tens of polls). Up and
     * down alike: about one read in two finds the last byte missing. */
    lf_ns step = p->ct / 8;
    if (p->ta[id] / 16 > step)
        step = p->ta[id] / 16;
    if (missing) {
        p->ta[id] += step;
        return;
    }
    if (p->ta[id] == 0)
        p->paced = 0;               /* complete even at no turnaround: observe again */
    p->ta[id] = p->ta[id] > step ? p->ta[id] - step : 0;
}
