/* port_net.h - the network transports (tcp://, rfc2217://) behind the
 * port layer's line-level transport table (port_backend.h). Only the
 * transport map (port_transport.c) calls this: it parses the URL
 * (port_url.h) and opens the port with the transport and context prepared
 * here. */
#ifndef LF_PORT_NET_H
#define LF_PORT_NET_H

#include "fap_port.h"
#include "port/port_backend.h"
#include "port/port_link.h"   /* lf_port_link_slack_ns (engines used to find it here) */
#include "port/port_url.h"

/* The transport and a new context for the parsed URL u: refuses a kernel,
 * soft-RTS or GPIO direction mode (FAP_PORT_ENET485: direction is the
 * server's job); -ENOMEM. The open (lf_port_open_transport) owns *ctx
 * from then on (freed by the transport's destroy, also when the open fails)
 * and returns FAP_PORT_ERESOLVE, FAP_PORT_EREFUSED, -ECONNREFUSED,
 * -ETIMEDOUT, -EPROTO (rfc2217:// and no Telnet from the server),
 * -ECANCELED (the cancel fd turned readable while the open waited). */
int lf_port_net_prepare(const lf_port_url *u, const fap_port_options *o,
                        const lf_port_transport **tr, void **ctx);

#endif
