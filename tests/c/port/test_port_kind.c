/* test_port_kind.c - what a port string is (fap_port_kind: the one parse
 * of port_url.c) and what an open port can do (fap_port_caps), through the
 * public API only. */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include "fap_port.h"
#include "pty_util.h"
#include "unit.h"

static void test_kind_table(void)
{
    static const struct {
        const char *s;
        int kind;
    } rows[] = {
        {"/dev/ttyUSB0", FAP_PORT_KIND_DEVICE},
        {"/dev/pts/3", FAP_PORT_KIND_DEVICE},
        {"relative/ttyS0", FAP_PORT_KIND_DEVICE},
        {"", FAP_PORT_KIND_DEVICE},                    /* the open says ENOENT */
        {"tcp://192.0.2.7:4001", FAP_PORT_KIND_TCP},
        {"tcp://pi.local:2000?rtt_ms=5", FAP_PORT_KIND_TCP},
        {"rfc2217://[::1]:65535?connect_ms=100&option_ms=0", FAP_PORT_KIND_RFC2217},
        {"rfc2217://h:1", FAP_PORT_KIND_RFC2217},
        {"socket://h:1", FAP_PORT_KIND_OTHER},         /* pyserial's, not ours */
        {"loop://", FAP_PORT_KIND_OTHER},
        {"TCP://h:1", FAP_PORT_KIND_TCP},              /* RFC 3986: schemes are case-insensitive */
        {"Rfc2217://h:1", FAP_PORT_KIND_RFC2217},
        {"/dev/x://y", FAP_PORT_KIND_OTHER},
        {"tcp://", FAP_PORT_KIND_INVALID},
        {"tcp://host", FAP_PORT_KIND_INVALID},
        {"tcp://host:0", FAP_PORT_KIND_INVALID},
        {"tcp://host:1?x=1", FAP_PORT_KIND_INVALID},
        {"rfc2217://[::1", FAP_PORT_KIND_INVALID},
        {NULL, FAP_PORT_KIND_INVALID},
    };
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        int k = fap_port_kind(rows[i].s);
        if (k != rows[i].kind)
            fprintf(stderr, "%s: kind %d, expected %d\n", rows[i].s ? rows[i].s : "(null)", k,
                    rows[i].kind);
        CHECK_EQ(k, rows[i].kind);
    }
}

/* What the kind says is what the open does: OTHER and INVALID are refused
 * with FAP_PORT_EURL before anything is opened or looked up. */
static void test_open_agrees(void)
{
    const char *refused[] = {"socket://127.0.0.1:1", "tcp://host", "TCP://host"};
    for (size_t i = 0; i < sizeof refused / sizeof refused[0]; i++) {
        fap_port *p = NULL;
        CHECK_EQ(fap_port_open(&p, refused[i], NULL), FAP_PORT_EURL);
        CHECK(p == NULL);
    }
    fap_port *p = NULL;
    CHECK_EQ(fap_port_open(NULL, "tcp://127.0.0.1:1", NULL), -EINVAL);
    CHECK_EQ(fap_port_open(&p, NULL, NULL), -EINVAL);
}

static void test_caps(void)
{
    CHECK_EQ(fap_port_caps(NULL), 0);
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port *p = NULL;
    REQUIRE(fap_port_open(&p, t.name, NULL) == 0);
    CHECK_EQ(fap_port_kind(fap_port_path(p)), FAP_PORT_KIND_DEVICE);
    /* the transport's, not the mode in force: AUTO settled on NONE on a pty */
    CHECK_EQ(fap_port_mode(p), FAP_RS485_NONE);
    CHECK_EQ(fap_port_caps(p), FAP_PORT_CAP_RS485 | FAP_PORT_CAP_RTS | FAP_PORT_CAP_LOCK |
                                   FAP_PORT_CAP_PACED);
    CHECK_EQ(fap_port_caps(p) & FAP_PORT_CAP_NETWORK, 0);
    char note[8] = "x";
    CHECK_EQ(fap_port_warning(p, note, sizeof note), 0);   /* a device has none */
    CHECK_EQ(note[0], '\0');
    fap_port_close(p);
    tp_close(&t);
}

UNIT_MAIN(UNIT(test_kind_table), UNIT(test_open_agrees), UNIT(test_caps))
