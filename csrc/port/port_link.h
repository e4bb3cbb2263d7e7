/* port_link.h - what an engine may ask of the link under a port, beyond
 * the public fap_port.h (fap_port_caps): nothing here names a transport,
 * so engines include this, never port_internal.h or port_net.h. */
#ifndef LF_PORT_LINK_H
#define LF_PORT_LINK_H

#include "common/mono_clock.h"
#include "fap_port.h"

/* What a reply timeout must allow on top of the wire time for the link's
 * round trip: the URL's rtt_ms on a network transport, 0 on a device (the
 * transport's slack_ns, port_backend.h). */
lf_ns lf_port_link_slack_ns(const fap_port *p);

#endif
