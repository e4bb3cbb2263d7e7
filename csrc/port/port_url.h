/* port_url.h - "tcp://host:port?k=v" and "rfc2217://host:port?k=v": the
 * network transports' addresses (docs/port.md, "Network transports").
 * Sans-I/O: parsing only, no name lookup. */
#ifndef LF_PORT_URL_H
#define LF_PORT_URL_H

typedef enum lf_port_scheme {
    LF_PORT_DEVICE = 0,      /* no "://": a device path */
    LF_PORT_TCP = 1,         /* raw TCP: ser2net raw, NPort "TCP server" */
    LF_PORT_RFC2217 = 2      /* Telnet COM-PORT-CONTROL */
} lf_port_scheme;

/* Defaults of the query parameters. */
#define LF_URL_CONNECT_MS_DEFAULT 3000u   /* connect_ms: TCP connect + RFC 2217 start */
#define LF_URL_RTT_MS_DEFAULT 20u         /* rtt_ms: added to reply timeouts */
#define LF_URL_OPTION_MS_DEFAULT 300u     /* option_ms: wait for an RFC 2217 answer */
#define LF_URL_MS_MAX 600000u             /* 10 minutes: any larger value is a typo */

typedef struct lf_port_url {
    lf_port_scheme scheme;
    char host[256];          /* name or address, without [] for IPv6 */
    char port[6];            /* decimal 1..65535 */
    unsigned connect_ms;
    unsigned rtt_ms;
    unsigned option_ms;
} lf_port_url;

/* The scheme of s: LF_PORT_DEVICE when s has no "://"; -1 for a "://" with
 * a scheme we do not know. */
int lf_port_url_scheme(const char *s);

/* Parse s into *u. 0, or FAP_PORT_EURL: unknown scheme, no host, no or bad
 * port (not 1..65535), unknown or bad query parameter, too long. */
int lf_port_url_parse(const char *s, lf_port_url *u);

#endif
