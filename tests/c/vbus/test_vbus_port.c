/* test_vbus_port.c - the port layer (fap_port) on virtual bus ports: what
 * the protocol engines will do in their tests. Echo suppression on an echo
 * bus, a collision seen through the echo, a disconnect and reopen. */
#include <errno.h>
#include <string.h>

#include "fap_port.h"
#include "fap_vbus.h"
#include "unit.h"
#include "vbus_test_io.h"

#define WAIT_NS (3LL * 1000000000LL)

static fap_vbus *open_bus(unsigned n, unsigned baud, int echo)
{
    fap_vbus_options o;
    fap_vbus_options_init(&o);
    o.n_ports = n;
    o.baud = baud;
    o.echo = echo;
    fap_vbus *bus = NULL;
    int r = fap_vbus_open(&bus, &o);
    CHECK_EQ(r, 0);
    return r == 0 ? bus : NULL;
}

static fap_port *open_port(fap_vbus *bus, unsigned i, int echo_suppression)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.baud = 9600;
    o.echo_suppression = echo_suppression;
    fap_port *p = NULL;
    int r = fap_port_open(&p, fap_vbus_port_path(bus, i), &o);
    CHECK_EQ(r, 0);
    return r == 0 ? p : NULL;
}

/* read exactly n bytes through the port layer before a deadline */
static ssize_t port_read_n(fap_port *p, uint8_t *buf, size_t n)
{
    size_t got = 0;
    int64_t deadline = fap_port_now_ns() + WAIT_NS;
    while (got < n) {
        ssize_t r = fap_port_read(p, buf + got, n - got, deadline);
        if (r <= 0)
            return got ? (ssize_t)got : r;
        got += (size_t)r;
    }
    return (ssize_t)got;
}

static void test_echo_suppression_on_an_echo_bus(void)
{
    fap_vbus *bus = open_bus(2, 0, 1);
    REQUIRE(bus);
    fap_port *a = open_port(bus, 0, 1);
    fap_port *b = open_port(bus, 1, 0);
    if (!a || !b)
        goto out;
    CHECK_EQ(fap_port_mode(a), FAP_RS485_NONE);   /* a pty has no kernel RS-485 */
    CHECK_EQ(fap_port_write(a, "\x7e\x10\x20", 3), 3);
    uint8_t got[8];
    /* b (no suppression) hears the frame; its own echo needs no handling here */
    CHECK_EQ(port_read_n(b, got, 3), 3);
    CHECK_MEM(got, "\x7e\x10\x20", 3);
    /* a's echo was consumed by the write: the next byte a reads is b's */
    CHECK_EQ(fap_port_write(b, "R", 1), 1);
    CHECK_EQ(port_read_n(a, got, 1), 1);
    CHECK_EQ(got[0], 'R');
    fap_port_stats st;
    fap_port_get_stats(a, &st);
    CHECK_EQ(st.echo_bytes, 3);
    CHECK_EQ(st.collisions, 0);
out:
    fap_port_close(a);
    fap_port_close(b);
    fap_vbus_close(bus);
}

static void test_collision_seen_through_the_echo(void)
{
    fap_vbus *bus = open_bus(3, 9600, 1);
    REQUIRE(bus);
    fap_port *a = open_port(bus, 0, 1);
    int other = vt_open(fap_vbus_port_path(bus, 1));
    CHECK(other >= 0);
    if (!a || other < 0)
        goto out;
    uint8_t jam[64];
    memset(jam, 0x33, sizeof jam);
    /* port 1 holds the wire for ~67 ms; a's frame starts inside that */
    CHECK_EQ(vt_write_all(other, jam, sizeof jam), 0);
    CHECK_EQ(fap_port_write(a, "\x01\x02\x03\x04", 4), FAP_PORT_ECOLLISION);
    fap_vbus_stats st;
    fap_vbus_get_stats(bus, &st);
    CHECK_EQ(st.collisions, 1);
out:
    if (other >= 0)
        close(other);
    fap_port_close(a);
    fap_vbus_close(bus);
}

static void test_disconnect_then_reopen(void)
{
    fap_vbus *bus = open_bus(2, 0, 0);
    REQUIRE(bus);
    fap_port *a = open_port(bus, 0, 0);
    fap_port *b = open_port(bus, 1, 0);
    if (!a || !b)
        goto out;
    CHECK_EQ(fap_vbus_disconnect(bus, 1, 100), 0);
    uint8_t got[4];
    ssize_t r = fap_port_read(b, got, sizeof got, fap_port_now_ns() + WAIT_NS);
    CHECK(r == -EIO || r == -ENXIO);
    /* reopen fails while the port is away, then works at the same path */
    int64_t deadline = fap_port_now_ns() + WAIT_NS;
    int rr;
    int failures = 0;
    while ((rr = fap_port_reopen(b)) != 0 && fap_port_now_ns() < deadline) {
        failures++;
        CHECK_EQ(rr, -ENOENT);
        poll(NULL, 0, 5);   /* a node's reopen pacing */
    }
    CHECK_EQ(rr, 0);
    CHECK(failures > 0);
    CHECK_EQ(fap_port_write(a, "back", 4), 4);
    CHECK_EQ(port_read_n(b, got, 4), 4);
    CHECK_MEM(got, "back", 4);
out:
    fap_port_close(a);
    fap_port_close(b);
    fap_vbus_close(bus);
}

UNIT_MAIN(
    UNIT(test_echo_suppression_on_an_echo_bus),
    UNIT(test_collision_seen_through_the_echo),
    UNIT(test_disconnect_then_reopen)
)
