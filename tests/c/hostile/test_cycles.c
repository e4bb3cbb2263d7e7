/* Open/close cycles of every handle kind (port, vbus, FAP handle master and
 * slave, classic API, exec master and slave, mikroC context and the global
 * vendor contexts): fds and threads must come back to where they started.
 * Memory: LeakSanitizer in the ASan build (CI's sanitizer loop) and
 * valgrind in .ci/leak.sh check that nothing leaks. CYCLES env: count. */
#include <dirent.h>
#include <errno.h>
#include <stdlib.h>

#include "exec_async_engine.h"
#include "fap.h"
#include "fapx.h"
#include "fap_port.h"
#include "fap_vbus.h"
#include "mikroc_rs485.h"
#include "unit.h"
#include "exec_echo.h"

static int count_dir(const char *path)
{
    DIR *d = opendir(path);
    if (!d)
        return -1;
    int n = 0;
    while (readdir(d))
        n++;
    closedir(d);
    return n;
}

static int fds(void) { return count_dir("/proc/self/fd"); }
static int threads(void) { return count_dir("/proc/self/task"); }

static void one_cycle(void)
{
    fap_vbus_options bo;
    fap_vbus_options_init(&bo);
    bo.n_ports = 3;
    fap_vbus *b = NULL;
    REQUIRE(fap_vbus_open(&b, &bo) == 0);
    const char *p0 = fap_vbus_port_path(b, 0), *p1 = fap_vbus_port_path(b, 1);
    fap_port_options po;
    fap_port_options_init(&po);
    po.rs485_mode = FAP_RS485_NONE;

    fap_port *p = NULL;
    REQUIRE(fap_port_open(&p, p0, &po) == 0);
    CHECK_EQ(fap_port_reopen(p), 0);
    fap_port_close(p);

    fapx_options o;
    fapx_options_init(&o);
    o.port = po;
    fapx *m = NULL, *s = NULL;
    REQUIRE(fapx_open(&m, p0, &o) == 0);
    o.mode = FAPX_SLAVE;
    o.id = 1;
    REQUIRE(fapx_open(&s, p1, &o) == 0);
    CHECK_EQ(fapx_add_slave(m, 1), 0);
    CHECK_EQ(fapx_tx(m, 1, "x", 1), 0);
    fapx_close(s);
    fapx_close(m);

    fapx_options co;
    fapx_options_init(&co);
    co.port = po;
    fapClassicSetOptions(&co);
    REQUIRE(fapInit((char *)p0, 115200) == GOOD);
    fapT cfg = {.id = 0, .mode = FAP_MASTER, .idcTime = 1};
    CHECK_EQ(fapConfig(&cfg), GOOD);
    fapClassicClose();
    fapClassicSetOptions(NULL);

    execMaster *em = NULL;
    REQUIRE(execMasterOpen(&em, p0, &po, NULL) == 0);
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    so.node = 2;
    execSlave *es = NULL;
    REQUIRE(execSlaveOpen(&es, p1, &po, &so, test_exec_echo, NULL) == 0);
    execSlaveClose(es);
    execMasterClose(em);

    mikrocRS485_ctx c;
    mikrocRS485_CtxInitMaster(&c);
    REQUIRE(mikrocRS485_CtxOpen(&c, p0, 0, &po) == 0);
    mikrocRS485_CtxClose(&c);
    RS485Master_Init();
    REQUIRE(mikrocRS485_Open(p1, 0, &po) == 0);
    mikrocRS485_Close();

    fap_vbus_close(b);
}

static void test_cycles_flat(void)
{
    const char *env = getenv("CYCLES");
    int n = env ? atoi(env) : 20;
    one_cycle();                       /* first use: lazy one-time allocations */
    int f0 = fds(), t0 = threads();
    for (int i = 0; i < n; i++)
        one_cycle();
    CHECK_EQ(fds(), f0);
    CHECK_EQ(threads(), t0);
    printf("cycles: %d, fds %d, threads %d\n", n, f0, t0);
}

UNIT_MAIN(UNIT(test_cycles_flat))
