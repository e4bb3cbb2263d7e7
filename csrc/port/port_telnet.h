/* port_telnet.h - the Telnet side of RFC 2217, sans-I/O: data bytes out of
 * a received stream (IAC IAC -> 0xFF, commands taken out, a command split
 * across reads kept in the state), data escaped for sending, and the
 * COM-PORT-CONTROL subnegotiations built and decoded. The socket, the
 * waits and the policy live in port_net.c. Binary mode both ways is
 * negotiated, so CR NUL and CR LF are data like any other bytes. */
#ifndef LF_PORT_TELNET_H
#define LF_PORT_TELNET_H

#include <stddef.h>
#include <stdint.h>

enum {
    LF_TN_SE = 240, LF_TN_SB = 250, LF_TN_WILL = 251, LF_TN_WONT = 252,
    LF_TN_DO = 253, LF_TN_DONT = 254, LF_TN_IAC = 255,
    LF_TN_OPT_BINARY = 0, LF_TN_OPT_ECHO = 1, LF_TN_OPT_SGA = 3,
    LF_TN_OPT_COMPORT = 44,
    /* COM-PORT-OPTION commands, client to server (server answers +100) */
    LF_CPC_SET_BAUDRATE = 1, LF_CPC_SET_DATASIZE = 2, LF_CPC_SET_PARITY = 3,
    LF_CPC_SET_STOPSIZE = 4, LF_CPC_SET_CONTROL = 5, LF_CPC_PURGE_DATA = 12,
    LF_CPC_SERVER = 100,
    /* values */
    LF_CPC_PARITY_NONE = 1, LF_CPC_STOP_1 = 1,
    LF_CPC_CONTROL_NOFLOW = 1, LF_CPC_CONTROL_DTR_ON = 8, LF_CPC_CONTROL_RTS_ON = 11,
    LF_CPC_PURGE_RX = 1, LF_CPC_PURGE_TX = 2, LF_CPC_PURGE_BOTH = 3,
};

#define LF_TN_SB_MAX 32   /* longest subnegotiation kept; longer ones are cut */
/* Longest subnegotiation read at all (its bytes on the wire): one that has
 * not ended by then is dropped and the parser is back on data, so a server
 * that opens an SB and never closes it cannot swallow the stream for good.
 * COM-PORT-OPTION's longest (SIGNATURE text) is far below. */
#define LF_TN_SB_WIRE_MAX 1024

typedef struct lf_telnet {
    uint8_t state;           /* parser state (port_telnet.c) */
    uint8_t verb;            /* WILL/WONT/DO/DONT being read */
    uint8_t sb[LF_TN_SB_MAX];
    size_t sb_len;
    size_t sb_wire;          /* bytes of the current SB read so far */
    uint64_t cmds;           /* commands seen (any IAC sequence but IAC IAC) */
    uint64_t sb_dropped;     /* subnegotiations cut at LF_TN_SB_WIRE_MAX */
} lf_telnet;

/* A command found in the stream: verb is WILL/WONT/DO/DONT with opt, or SB
 * with the subnegotiation's bytes (option first, unescaped) in sb/len. */
typedef void (*lf_telnet_cmd_fn)(void *ctx, uint8_t verb, uint8_t opt,
                                 const uint8_t *sb, size_t len);

void lf_telnet_init(lf_telnet *t);

/* Parse n received bytes: the data bytes go to out (room for n: data is
 * never longer than its encoding), commands to cmd. Returns the data count. */
size_t lf_telnet_rx(lf_telnet *t, const uint8_t *in, size_t n, uint8_t *out,
                    lf_telnet_cmd_fn cmd, void *ctx);

/* Escape n data bytes into out (room for 2n): every 0xFF doubled.
 * Returns the encoded length. */
size_t lf_telnet_escape(const uint8_t *in, size_t n, uint8_t *out);

/* IAC SB COM-PORT-OPTION cmd value... IAC SE into out (room for 16):
 * value is vlen bytes (1 or 4), escaped. Returns the length. */
size_t lf_telnet_cpc(uint8_t cmd, const uint8_t *value, size_t vlen, uint8_t *out);

#endif
