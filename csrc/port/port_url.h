/* port_url.h - "tcp://host:port?k=v" and "rfc2217://host:port?k=v": the
 * network transports' addresses (docs/port.md, "Network transports").
 * Sans-I/O: parsing only, no name lookup. */
#ifndef LF_PORT_URL_H
#define LF_PORT_URL_H

typedef enum lf_port_scheme {
    LF_PORT_OTHER = -1,      /* a "://" with a scheme we do not open */
    LF_PORT_DEVICE = 0,      /* no "://": a device path */
    LF_PORT_TCP = 1,         /* raw TCP: ser2net raw, NPort "TCP server" */
    LF_PORT_RFC2217 = 2      /* Telnet COM-PORT-CONTROL */
} lf_port_scheme;

/* Defaults of the query parameters. */
#define LF_URL_CONNECT_MS_DEFAULT 3000u   /* connect_ms: TCP connect + RFC 2217 start */
#define LF_URL_RTT_MS_DEFAULT 20u         /* rtt_ms: added to reply timeouts */
#define LF_URL_OPTION_MS_DEFAULT 3000u    /* option_ms: wait for an RFC 2217 answer (pyserial waits 3 s too) */
#define LF_URL_MS_MAX 600000u             /* 10 minutes: any larger value is a typo */

typedef struct lf_port_url {
    lf_port_scheme scheme;
    char host[256];          /* name or address, without [] for IPv6 */
    char port[6];            /* decimal 1..65535 */
    unsigned connect_ms;
    unsigned rtt_ms;
    unsigned option_ms;
} lf_port_url;

/* Parse s into *u: the one reading of a port string (fap_port_kind and
 * the transport map, port_transport.c, both call it). 0 for a URL that
 * parses; else FAP_PORT_EURL, with u->scheme still saying what s is:
 * LF_PORT_DEVICE (no "://", a device path), LF_PORT_OTHER (a scheme we do
 * not know, or NULL), or the scheme of a URL that does not parse (no host,
 * no or bad port, unknown or bad query parameter, too long). */
int lf_port_url_parse(const char *s, lf_port_url *u);

#endif
