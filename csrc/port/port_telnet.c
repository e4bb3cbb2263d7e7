/* port_telnet.c - Telnet stream parsing and escaping for RFC 2217 (see
 * port_telnet.h). */
#include "port/port_telnet.h"

#include <string.h>

enum { ST_DATA, ST_IAC, ST_OPT, ST_SB, ST_SB_IAC };

void lf_telnet_init(lf_telnet *t)
{
    memset(t, 0, sizeof *t);
}

size_t lf_telnet_rx(lf_telnet *t, const uint8_t *in, size_t n, uint8_t *out,
                    lf_telnet_cmd_fn cmd, void *ctx)
{
    size_t o = 0;
    for (size_t i = 0; i < n; i++) {
        uint8_t b = in[i];
        switch (t->state) {
        case ST_DATA:
            if (b == LF_TN_IAC)
                t->state = ST_IAC;
            else
                out[o++] = b;
            break;
        case ST_IAC:
            t->state = ST_DATA;
            if (b == LF_TN_IAC) {
                out[o++] = b;                 /* IAC IAC: a data 0xFF */
            } else if (b >= LF_TN_WILL && b <= LF_TN_DONT) {
                t->verb = b;
                t->state = ST_OPT;
            } else if (b == LF_TN_SB) {
                t->sb_len = t->sb_wire = 0;
                t->state = ST_SB;
                t->cmds++;
            } else {
                t->cmds++;                    /* NOP, GA, ...: nothing to do */
            }
            break;
        case ST_OPT:
            t->state = ST_DATA;
            t->cmds++;
            if (cmd)
                cmd(ctx, t->verb, b, NULL, 0);
            break;
        case ST_SB:
        case ST_SB_IAC:
            if (++t->sb_wire > LF_TN_SB_WIRE_MAX) {
                /* an SB that never ends: dropped; this byte is the stream's */
                t->sb_dropped++;
                t->sb_len = t->sb_wire = 0;
                if (b == LF_TN_IAC) {
                    t->state = ST_IAC;
                } else {
                    t->state = ST_DATA;
                    out[o++] = b;
                }
                break;
            }
            if (t->state == ST_SB) {
                if (b == LF_TN_IAC)
                    t->state = ST_SB_IAC;
                else if (t->sb_len < LF_TN_SB_MAX)
                    t->sb[t->sb_len++] = b;
                break;
            }
            if (b == LF_TN_IAC) {             /* escaped 0xFF inside SB */
                if (t->sb_len < LF_TN_SB_MAX)
                    t->sb[t->sb_len++] = b;
                t->state = ST_SB;
            } else {                          /* SE (or a broken SB: end it) */
                t->state = ST_DATA;
                if (cmd && t->sb_len > 0)
                    cmd(ctx, LF_TN_SB, t->sb[0], t->sb + 1, t->sb_len - 1);
            }
            break;
        default:
            t->state = ST_DATA;
        }
    }
    return o;
}

size_t lf_telnet_escape(const uint8_t *in, size_t n, uint8_t *out)
{
    size_t o = 0;
    for (size_t i = 0; i < n; i++) {
        out[o++] = in[i];
        if (in[i] == LF_TN_IAC)
            out[o++] = LF_TN_IAC;
    }
    return o;
}

size_t lf_telnet_cpc(uint8_t cmd, const uint8_t *value, size_t vlen, uint8_t *out)
{
    size_t o = 0;
    out[o++] = LF_TN_IAC;
    out[o++] = LF_TN_SB;
    out[o++] = LF_TN_OPT_COMPORT;
    out[o++] = cmd;
    if (vlen > 4)
        vlen = 4;
    o += lf_telnet_escape(value, vlen, out + o);
    out[o++] = LF_TN_IAC;
    out[o++] = LF_TN_SE;
    return o;
}
