/* port_net.h - the network transports (tcp://, rfc2217://) behind the
 * port layer's backend table: fap_port_open hands a URL here. */
#ifndef LF_PORT_NET_H
#define LF_PORT_NET_H

#include "common/mono_clock.h"
#include "fap_port.h"

/* fap_port_open for a URL (port_url.h): parse it, refuse a kernel or
 * soft-RTS direction mode (FAP_PORT_ENET485: direction is the server's
 * job), connect. Same returns as fap_port_open, plus FAP_PORT_EURL,
 * FAP_PORT_ERESOLVE, FAP_PORT_EREFUSED, -ECONNREFUSED, -ETIMEDOUT, -EPROTO
 * (rfc2217:// and no Telnet from the server), -ECANCELED (*cancel_fd, NULL
 * = none, turned readable while the open waited). */
int lf_port_net_open(fap_port **out, const char *url, const fap_port_options *o,
                     const int *cancel_fd);

/* What a reply timeout must allow on top of the wire time for the link's
 * round trip: the URL's rtt_ms on a network transport, 0 on a device. */
lf_ns lf_port_link_slack_ns(const fap_port *p);

#endif
