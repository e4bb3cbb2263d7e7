/* rx_plan.c - when to read a frame or a reply (see rx_plan.h). No I/O, no
 * clock: every time is the caller's. */
#include "port/rx_plan.h"

/* The hold starts when the reader READ the first bytes, which may be a
 * wake-up latency after they arrived: end it this much early, so a late
 * wake-up does not become a late answer (measured: 50-200 us p50 on a
 * loaded 2-core box). */
#define HOLD_MARGIN_NS (150 * LF_NS_PER_US)
/* A shorter sleep costs more (timer, epoll changes) than the wake-ups it
 * saves: at 1 Mbaud a short frame comes in one or two pieces anyway. */
#define HOLD_MIN_NS (100 * LF_NS_PER_US)

lf_ns lf_rx_hold_ns(unsigned baud, size_t missing)
{
    return baud ? lf_rx_hold_ct_ns(lf_char_time_ns(baud), missing) : 0;
}

lf_ns lf_rx_hold_ct_ns(lf_ns ct, size_t missing)
{
    if (missing < 2 || ct <= 0)
        return 0;
    lf_ns hold = (lf_ns)(missing - 1) * ct - (ct > HOLD_MARGIN_NS ? ct : HOLD_MARGIN_NS);
    return hold >= HOLD_MIN_NS ? hold : 0;
}

int lf_rx_at_baud(lf_ns gap, lf_ns ct, size_t n)
{
    return gap * 10 >= ct * 7 * (lf_ns)n;
}

lf_ns lf_rx_rest_deadline(lf_ns ct, size_t n, lf_ns now, lf_ns deadline)
{
    lf_ns rest = now + (lf_ns)n * ct;
    return rest < deadline ? rest : deadline;
}

void lf_rx_plan_init(lf_rx_plan *pl, unsigned baud, lf_rx_link *link, int any_hold_clears)
{
    *pl = (lf_rx_plan){
        .ct = baud ? lf_char_time_ns(baud) : 0,
        .link = link,
        .any_hold_clears = any_hold_clears,
    };
}

static lf_rx_action act(lf_rx_act a, lf_rx_why why, lf_ns until)
{
    return (lf_rx_action){ .act = a, .why = why, .until = until };
}

/* A sleep until t, never past the deadline (then the next read's plan is
 * COMPLETE: DEADLINE). */
static lf_rx_action sleep_until(lf_rx_plan *pl, lf_rx_why why, lf_ns t, lf_ns deadline)
{
    pl->capped = t >= deadline;
    return act(LF_RX_SLEEP_UNTIL, why, pl->capped ? deadline : t);
}

lf_rx_action lf_rx_plan_piece(lf_rx_plan *pl, const lf_rx_piece *in)
{
    lf_ns ct = pl->ct, now = in->now, last = pl->t_last;
    lf_rx_link *link = pl->link;
    if (in->first)
        pl->trusted = 0;
    if (link) {
        if (in->slept_to && in->missing == 0 && (pl->any_hold_clears || pl->trusted) &&
            now - in->slept_to <= ct) {
            /* Complete at a hold's end: the link outran the baud, unless
             * the wake-up itself came late by more than a character time
             * (a loaded machine): then the frame had all the time it
             * needed at the baud, and observing again would only cost the
             * next frame a wake-up. */
            link->at_baud = 0;
        } else if (!in->first && !in->slept_to && last > 0 && ct > 0) {
            /* a piece as the wire brought it: the link's pace */
            link->at_baud = lf_rx_at_baud(now - last, ct, in->n);
        }
    }
    /* The pace this frame showed: the piece's bytes over the time since
     * the previous one (never slower than the baud). */
    pl->t_last = in->missing ? now : 0;
    lf_ns hold = 0;
    lf_rx_why why = LF_RX_HOLD;
    if (!in->first && last > 0 && in->missing) {
        lf_ns seen = (now - last) / (lf_ns)in->n;
        if (seen < 1)
            seen = 1;
        lf_ns c = ct ? ct : seen;
        hold = lf_rx_hold_ct_ns(seen < c ? seen : c, in->missing);
    }
    if (in->first) {
        /* the last frames showed the link at the baud: hold from here */
        pl->trusted = link && link->at_baud && ct > 0;
        pl->observed = pl->trusted;
        if (pl->trusted) {
            hold = lf_rx_hold_ct_ns(ct, in->missing);
            why = LF_RX_HOLD_KEPT;
        }
    } else {
        pl->observed = 1;
    }
    int capped = pl->capped && in->slept_to;
    pl->capped = 0;
    if (in->missing == 0)
        return act(LF_RX_COMPLETE, LF_RX_DONE, 0);
    if (capped)
        return act(LF_RX_COMPLETE, LF_RX_DEADLINE, 0);
    if (hold == 0)   /* the first piece (the next shows the pace), or the last bytes */
        return act(LF_RX_WATCH_UNTIL, pl->observed ? LF_RX_LAST : LF_RX_OBSERVE, in->deadline);
    return sleep_until(pl, why, now + hold, in->deadline);
}

lf_rx_action lf_rx_plan_reply(lf_rx_plan *pl, lf_rx_reply_mode mode, size_t want,
                              lf_ns not_before, lf_ns now, lf_ns deadline)
{
    pl->stage = LF_RX_REPLY_NONE;
    pl->capped = 0;
    int sleep;
    if (mode == LF_RX_REPLY_PREDICTED)
        sleep = not_before != 0;
    else   /* a reply shorter than a hold is worth (a short frame at 1 Mbaud) comes
            * in a piece or two anyway, and a sleep's timer slack could make it late */
        sleep = pl->link && pl->link->at_baud && lf_rx_hold_ct_ns(pl->ct, want) > 0 &&
                not_before > now && deadline > now;
    if (!sleep)
        return act(LF_RX_WATCH_UNTIL, LF_RX_OBSERVE, deadline);
    pl->stage = LF_RX_REPLY_ASLEEP;
    /* the reply cannot be complete before not_before: one sleep, one read */
    return sleep_until(pl, LF_RX_REPLY, not_before, deadline);
}

lf_rx_action lf_rx_plan_reply_read(lf_rx_plan *pl, lf_rx_reply_mode mode,
                                   const lf_rx_reply_read *in)
{
    lf_rx_reply_stage stage = pl->stage;
    int capped = pl->capped;
    pl->stage = LF_RX_REPLY_NONE;
    pl->capped = 0;
    if (mode == LF_RX_REPLY_EXPECTED) {
        if (capped)
            return act(LF_RX_COMPLETE, LF_RX_DEADLINE, 0);   /* the deadline came first */
        if (in->got > 0 && in->got >= in->want) {
            if (pl->link && in->now - in->slept_to <= pl->ct)
                pl->link->at_baud = 0;   /* complete at an on-time wake: the link is faster */
            return act(LF_RX_COMPLETE, LF_RX_DONE, 0);
        }
        if (in->got > 0)   /* the rest at the baud's pace, bounded by its wire time */
            return act(LF_RX_WATCH_UNTIL, LF_RX_REPLY_REST,
                       lf_rx_rest_deadline(pl->ct, in->want - in->got, in->now, in->deadline));
        /* nothing yet (a slow responder): wait for it on the fd as before */
        return act(LF_RX_WATCH_UNTIL, LF_RX_OBSERVE, in->deadline);
    }
    size_t missing = in->missing;
    if (stage == LF_RX_REPLY_ASLEEP && !in->done && !missing && !in->got)
        missing = in->want;          /* nothing came: the whole reply */
    /* More than the last byte missing: hold for all but the last at the
     * baud's pace; the last one (or what the hold did not bring) is waited
     * for on the port, so the reply is not later than the wire. */
    if (stage == LF_RX_REPLY_ASLEEP && missing > 1) {
        lf_ns t = in->now + (lf_ns)(missing - 1) * pl->ct;
        pl->stage = LF_RX_REPLY_HOLD;
        return act(LF_RX_SLEEP_UNTIL, LF_RX_REPLY_REST, t < in->deadline ? t : in->deadline);
    }
    return act(LF_RX_WATCH_UNTIL, in->done || !missing ? LF_RX_DONE : LF_RX_LAST, LF_NEVER);
}

int lf_rx_plan_sent(lf_rx_plan *pl, size_t missing)
{
    if (pl->stage == LF_RX_REPLY_ASLEEP || (pl->stage == LF_RX_REPLY_HOLD && !missing)) {
        pl->stage = LF_RX_REPLY_NONE;
        pl->capped = 0;
        return 1;
    }
    return 0;
}
