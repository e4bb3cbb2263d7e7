/* port_url.c - parse the network transports' URLs (see port_url.h). */
#include "port/port_url.h"

#include <stddef.h>
#include <string.h>
#include <strings.h>

#include "fap_port.h"

static const struct {
    const char *prefix;
    lf_port_scheme scheme;
} schemes[] = {
    {"tcp://", LF_PORT_TCP},
    {"rfc2217://", LF_PORT_RFC2217},
};

static lf_port_scheme url_scheme(const char *s)
{
    if (!s)
        return LF_PORT_OTHER;
    if (!strstr(s, "://"))
        return LF_PORT_DEVICE;
    for (size_t i = 0; i < sizeof schemes / sizeof schemes[0]; i++)
        if (strncasecmp(s, schemes[i].prefix, strlen(schemes[i].prefix)) == 0)   /* RFC 3986: a scheme is case-insensitive */
            return schemes[i].scheme;
    return LF_PORT_OTHER;
}

/* Decimal digits [s, e) as a number <= max; -1 if empty, not digits or larger. */
static long parse_num(const char *s, const char *e, long max)
{
    if (s >= e)
        return -1;
    long v = 0;
    for (; s < e; s++) {
        if (*s < '0' || *s > '9')
            return -1;
        v = v * 10 + (*s - '0');
        if (v > max)
            return -1;
    }
    return v;
}

static int parse_query(const char *q, lf_port_url *u)
{
    static const struct {
        const char *key;
        size_t off;
    } keys[] = {
        {"connect_ms", offsetof(lf_port_url, connect_ms)},
        {"rtt_ms", offsetof(lf_port_url, rtt_ms)},
        {"option_ms", offsetof(lf_port_url, option_ms)},
    };
    for (;;) {                        /* key=value[&key=value...], none empty */
        const char *amp = strchr(q, '&');
        const char *end = amp ? amp : q + strlen(q);
        const char *eq = memchr(q, '=', (size_t)(end - q));
        if (!eq)
            return FAP_PORT_EURL;
        size_t klen = (size_t)(eq - q);
        int found = 0;
        for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++) {
            if (strlen(keys[i].key) != klen || strncmp(q, keys[i].key, klen) != 0)
                continue;
            long v = parse_num(eq + 1, end, LF_URL_MS_MAX);
            if (v < 0)
                return FAP_PORT_EURL;
            *(unsigned *)(void *)((char *)u + keys[i].off) = (unsigned)v;
            found = 1;
        }
        if (!found)
            return FAP_PORT_EURL;
        if (!amp)
            break;
        q = amp + 1;
    }
    return 0;
}

int lf_port_url_parse(const char *s, lf_port_url *u)
{
    memset(u, 0, sizeof *u);
    u->scheme = url_scheme(s);
    if (u->scheme == LF_PORT_DEVICE || u->scheme == LF_PORT_OTHER)
        return FAP_PORT_EURL;
    u->connect_ms = LF_URL_CONNECT_MS_DEFAULT;
    u->rtt_ms = LF_URL_RTT_MS_DEFAULT;
    u->option_ms = LF_URL_OPTION_MS_DEFAULT;
    const char *h = strstr(s, "://") + 3;
    const char *q = strchr(h, '?');
    const char *end = q ? q : h + strlen(h);
    const char *hend, *colon;
    if (*h == '[') {                        /* [IPv6]:port */
        const char *rb = memchr(h, ']', (size_t)(end - h));
        if (!rb || rb[1] != ':')
            return FAP_PORT_EURL;
        hend = rb;
        colon = rb + 1;
        h++;
    } else {
        colon = NULL;
        for (const char *c = h; c < end; c++)
            if (*c == ':')
                colon = c;
        if (!colon)
            return FAP_PORT_EURL;
        hend = colon;
    }
    size_t hlen = (size_t)(hend - h);
    if (hlen == 0 || hlen >= sizeof u->host || memchr(h, '/', hlen))
        return FAP_PORT_EURL;
    long port = parse_num(colon + 1, end, 65535);
    if (port < 1 || end - colon - 1 > 5)
        return FAP_PORT_EURL;
    memcpy(u->host, h, hlen);
    u->host[hlen] = '\0';
    memcpy(u->port, colon + 1, (size_t)(end - colon - 1));
    u->port[end - colon - 1] = '\0';
    return q ? parse_query(q + 1, u) : 0;
}
