/* The real-time option (port_rt.c, docs/realtime.md): the spec parser,
 * FAP_REALTIME, applying in a thread (policy, priority, affinity read back),
 * the check that leaves the caller alone, each engine's I/O thread taking
 * the settings (FAP engine thread, exec slave's serving thread, vbus relay),
 * and the refusals: a child without CAP_SYS_NICE / CAP_IPC_LOCK and with
 * RLIMIT_RTPRIO / RLIMIT_MEMLOCK at 0 gets the documented codes from
 * fap_port_rt_apply and from the opens. */
#include <dirent.h>
#include <linux/capability.h>
#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <sys/wait.h>

#include "exec_async_engine.h"
#include "fap.h"
#include "fap_port.h"
#include "fap_vbus.h"
#include "fapx.h"
#include "pty_util.h"
#include "unit.h"

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define SANITIZED 1   /* mlockall would pin the sanitizer's terabytes of shadow */
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define SANITIZED 1
#endif
#endif
#ifndef SANITIZED
#define SANITIZED 0
#endif

static fap_port_rt spec(const char *s)
{
    fap_port_rt rt = {FAP_RT_OFF, 0, 0, 0};
    char why[160];
    int err = fap_port_rt_parse(s, &rt, why, sizeof why);
    if (err)
        fprintf(stderr, "spec '%s': %s\n", s, why);
    CHECK_EQ(err, 0);
    return rt;
}

/* Port options for a pty (no RS-485 ioctls) with the real-time spec. */
static fap_port_options pty_opts(const char *rt)
{
    fap_port_options o;
    fap_port_options_init(&o);
    o.rs485_mode = FAP_RS485_NONE;
    o.rt = spec(rt);
    return o;
}

static void test_parse(void)
{
    fap_port_rt rt = spec("fifo:50,mlock,cpu=1");
    CHECK_EQ(rt.policy, FAP_RT_FIFO);
    CHECK_EQ(rt.priority, 50);
    CHECK_EQ(rt.mlock, 1);
    CHECK_EQ(rt.cpus, 2);
    rt = spec("cpu=0-2,rr:1,cpu=5");
    CHECK_EQ(rt.policy, FAP_RT_RR);
    CHECK_EQ(rt.priority, 1);
    CHECK_EQ(rt.mlock, 0);
    CHECK_EQ(rt.cpus, 0x27);
    rt = spec("cpu=63");
    CHECK(rt.cpus == UINT64_C(1) << 63);
    rt = spec("off");
    CHECK(rt.policy == FAP_RT_OFF && !rt.mlock && !rt.cpus);
    rt = spec("");
    CHECK(rt.policy == FAP_RT_OFF && !rt.mlock && !rt.cpus);
    CHECK_EQ(fap_port_rt_parse(NULL, &rt, NULL, 0), 0);

    static const struct { const char *spec, *says; } bad[] = {
        {"fifo:0", "'fifo:0'"}, {"fifo:100", "1..99"}, {"rr:", "unknown"},
        {"fifo:5x", "'fifo:5x'"}, {"cpu=64", "'cpu=64'"}, {"cpu=3-1", "'cpu=3-1'"},
        {"cpu=", "unknown"}, {"cpu=-1", "'cpu=-1'"}, {"mlock,mlock", "given already"},
        {"fifo:5,rr:5", "'rr:5'"}, {"off,mlock", "alone"}, {"fifo:5,,mlock", "empty"},
        {"mlock,", "comma"}, {"MLOCK", "unknown"}, {"fifo:0000000001", "'fifo:0000000001'"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        fap_port_rt keep = {FAP_RT_RR, 7, 1, 9};
        char why[160] = "";
        CHECK_EQ(fap_port_rt_parse(bad[i].spec, &keep, why, sizeof why), -EINVAL);
        int says = strstr(why, bad[i].says) != NULL;
        if (!says)
            fprintf(stderr, "spec %zu: unexpected reason: %s\n", i, why);
        CHECK(says);
        CHECK(keep.policy == FAP_RT_RR && keep.priority == 7 && keep.cpus == 9);  /* untouched */
    }
    char tiny[8];
    CHECK_EQ(fap_port_rt_parse("nope", &rt, tiny, sizeof tiny), -EINVAL);
    CHECK_EQ(strlen(tiny), 7);
    CHECK_EQ(fap_port_rt_parse("fifo:1", NULL, NULL, 0), -EINVAL);
}

static void test_env(void)
{
    fap_port_rt rt;
    char why[160];
    unsetenv("FAP_REALTIME");
    CHECK_EQ(fap_port_rt_from_env(&rt, why, sizeof why), 0);
    CHECK(rt.policy == FAP_RT_OFF && !rt.mlock && !rt.cpus);
    setenv("FAP_REALTIME", "rr:20,cpu=0", 1);
    CHECK_EQ(fap_port_rt_from_env(&rt, why, sizeof why), 0);
    CHECK(rt.policy == FAP_RT_RR && rt.priority == 20 && rt.cpus == 1);
    setenv("FAP_REALTIME", "fifo:hi", 1);
    CHECK_EQ(fap_port_rt_from_env(&rt, why, sizeof why), -EINVAL);
    CHECK(strncmp(why, "FAP_REALTIME: ", 14) == 0 && strstr(why, "'fifo:hi'"));
    unsetenv("FAP_REALTIME");
}

/* ---- what a thread has ------------------------------------------------- */

typedef struct seen {
    int policy, priority;
    uint64_t cpus;
} seen;

static seen seen_self(void)
{
    seen s = {0, 0, 0};
    struct sched_param sp;
    pthread_getschedparam(pthread_self(), &s.policy, &sp);
    s.priority = sp.sched_priority;
    cpu_set_t set;
    CPU_ZERO(&set);
    pthread_getaffinity_np(pthread_self(), sizeof set, &set);
    for (int c = 0; c < 64; c++)
        if (CPU_ISSET(c, &set))
            s.cpus |= UINT64_C(1) << c;
    return s;
}

static seen seen_tid(pid_t tid)
{
    seen s = {sched_getscheduler(tid), 0, 0};
    struct sched_param sp;
    if (sched_getparam(tid, &sp) == 0)
        s.priority = sp.sched_priority;
    cpu_set_t set;
    CPU_ZERO(&set);
    if (sched_getaffinity(tid, sizeof set, &set) == 0)
        for (int c = 0; c < 64; c++)
            if (CPU_ISSET(c, &set))
                s.cpus |= UINT64_C(1) << c;
    return s;
}

/* Threads of this process at SCHED_FIFO/RR with priority prio. */
static int rt_threads(int policy, int prio)
{
    DIR *d = opendir("/proc/self/task");
    if (!d)
        return -1;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        if (e->d_name[0] == '.')
            continue;
        seen s = seen_tid((pid_t)atoi(e->d_name));
        n += s.policy == policy && s.priority == prio;
    }
    closedir(d);
    return n;
}

/* Wait (bounded) until `want` threads run at policy/prio. */
static int wait_rt_threads(int policy, int prio, int want)
{
    int64_t end = tp_now_ns() + 5000000000LL;
    int n;
    while ((n = rt_threads(policy, prio)) != want && tp_now_ns() < end)
        sched_yield();
    return n;
}

static uint64_t online_cpus(void)
{
    cpu_set_t set;
    CPU_ZERO(&set);
    sched_getaffinity(0, sizeof set, &set);
    uint64_t m = 0;
    for (int c = 0; c < 64; c++)
        if (CPU_ISSET(c, &set))
            m |= UINT64_C(1) << c;
    return m;
}

static int lowest_cpu(void)
{
    uint64_t m = online_cpus();
    for (int c = 0; c < 64; c++)
        if (m & (UINT64_C(1) << c))
            return c;
    return 0;
}

/* Can this process have SCHED_FIFO 10 at all (CAP_SYS_NICE or RTPRIO)? */
static int privileged(void)
{
    fap_port_rt rt = {FAP_RT_FIFO, 10, 0, 0};
    int err = fap_port_rt_check(&rt);
    if (err == FAP_PORT_ERTPRIV && getenv("CI") == NULL) {
        fprintf(stderr, "note: no CAP_SYS_NICE / RLIMIT_RTPRIO here: the granted paths "
                        "are not run (CI requires them)\n");
        return 0;
    }
    CHECK_EQ(err, 0);
    return err == 0;
}

struct apply_arg {
    fap_port_rt rt;
    int rc;
    seen after;
};

static void *apply_main(void *arg)
{
    struct apply_arg *a = arg;
    a->rc = fap_port_rt_apply(&a->rt);
    a->after = seen_self();
    return NULL;
}

static void test_apply_in_thread(void)
{
    if (!privileged())
        return;
    seen before = seen_self();
    int cpu = lowest_cpu();
    struct apply_arg a = {{FAP_RT_FIFO, 10, 0, UINT64_C(1) << cpu}, -1, {0, 0, 0}};
    pthread_t th;
    REQUIRE(pthread_create(&th, NULL, apply_main, &a) == 0);
    pthread_join(th, NULL);
    CHECK_EQ(a.rc, 0);
    CHECK_EQ(a.after.policy, SCHED_FIFO);
    CHECK_EQ(a.after.priority, 10);
    CHECK(a.after.cpus == UINT64_C(1) << cpu);
    a = (struct apply_arg){{FAP_RT_RR, 3, 0, 0}, -1, {0, 0, 0}};
    REQUIRE(pthread_create(&th, NULL, apply_main, &a) == 0);
    pthread_join(th, NULL);
    CHECK_EQ(a.rc, 0);
    CHECK_EQ(a.after.policy, SCHED_RR);
    CHECK_EQ(a.after.priority, 3);
    seen now = seen_self();   /* the main thread was not touched */
    CHECK_EQ(now.policy, before.policy);
    CHECK(now.cpus == before.cpus);

    /* the check runs in a throwaway thread: the caller keeps its policy */
    fap_port_rt rt = {FAP_RT_FIFO, 10, 0, 0};
    CHECK_EQ(fap_port_rt_check(&rt), 0);
    CHECK_EQ(seen_self().policy, before.policy);
    /* values out of range are -EINVAL, not a privilege error */
    rt.priority = 100;
    CHECK_EQ(fap_port_rt_check(&rt), -EINVAL);
    rt = (fap_port_rt){(fap_rt_policy)7, 10, 0, 0};
    CHECK_EQ(fap_port_rt_apply(&rt), -EINVAL);
    rt = (fap_port_rt){FAP_RT_OFF, 5, 0, 0};
    CHECK_EQ(fap_port_rt_apply(&rt), -EINVAL);
    CHECK_EQ(fap_port_rt_apply(NULL), 0);
}

static void test_bad_cpu(void)
{
    uint64_t have = online_cpus();
    int missing = 63;
    while (missing > 0 && (have & (UINT64_C(1) << missing)))
        missing--;
    REQUIRE(!(have & (UINT64_C(1) << missing)));
    fap_port_rt rt = {FAP_RT_OFF, 0, 0, UINT64_C(1) << missing};
    CHECK_EQ(fap_port_rt_check(&rt), FAP_PORT_ERTCPU);
    /* one good CPU and one missing: refused, not quietly narrowed */
    rt.cpus |= UINT64_C(1) << lowest_cpu();
    CHECK_EQ(fap_port_rt_check(&rt), FAP_PORT_ERTCPU);
    CHECK(strstr(fap_port_strerror(FAP_PORT_ERTCPU), "CPU") != NULL);

    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = pty_opts("");
    o.rt = rt;
    fap_port *p = NULL;
    CHECK_EQ(fap_port_open(&p, t.name, &o), FAP_PORT_ERTCPU);
    CHECK(p == NULL);
    o.rt.cpus = 0;   /* nothing stayed open: the same path opens (exclusive) */
    CHECK_EQ(fap_port_open(&p, t.name, &o), 0);
    fap_port_close(p);
    close(t.master);
}

/* ---- engines' I/O threads --------------------------------------------- */

struct enter_arg {
    fap_port *p;
    int rc1, rc2;
    seen first, second;
};

static void *enter_main(void *arg)
{
    struct enter_arg *a = arg;
    a->rc1 = fap_port_rt_enter(a->p);
    a->first = seen_self();
    struct sched_param sp = {.sched_priority = 0};
    pthread_setschedparam(pthread_self(), SCHED_OTHER, &sp);   /* as if someone reset it */
    a->rc2 = fap_port_rt_enter(a->p);
    a->second = seen_self();
    return NULL;
}

static void test_port_enter(void)
{
    if (!privileged())
        return;
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options o = pty_opts("fifo:11");
    fap_port *p = NULL;
    MUST(fap_port_open(&p, t.name, &o) == 0);
    CHECK_EQ(seen_self().policy, SCHED_OTHER);   /* the open only checked */
    CHECK_EQ(fap_port_rt_enter(NULL), -EINVAL);
    struct enter_arg a = {p, -1, -1, {0, 0, 0}, {0, 0, 0}};
    pthread_t th;
    MUST(pthread_create(&th, NULL, enter_main, &a) == 0);
    pthread_join(th, NULL);
    CHECK_EQ(a.rc1, 0);
    CHECK_EQ(a.first.policy, SCHED_FIFO);
    CHECK_EQ(a.first.priority, 11);
    CHECK_EQ(a.rc2, 0);
    CHECK_EQ(a.second.policy, SCHED_OTHER);   /* applied once per thread and port */
    fap_port_stats st;
    fap_port_get_stats(p, &st);
    CHECK_EQ(st.rt_refused, 0);
    fap_port_close(p);
    close(t.master);
}

static int serve_handler(void *ctx, const execSlaveRequest *req, byte *reply, word cap)
{
    (void)ctx; (void)req; (void)reply; (void)cap;
    return -1;
}

struct serve_arg {
    execSlave *s;
    int rc;
    seen after;
};

static void *serve_main(void *arg)
{
    struct serve_arg *a = arg;
    a->rc = execSlaveServe(a->s, 0);
    a->after = seen_self();
    return NULL;
}

static void test_engines(void)
{
    if (!privileged())
        return;
    /* FAP: the engine thread (fapx_open starts it) runs at FIFO 12 */
    test_pty t;
    MUST(tp_open(&t) == 0);
    fapx_options fo;
    fapx_options_init(&fo);
    fo.mode = FAPX_MASTER;
    fo.id = 0;
    fo.port = pty_opts("fifo:12");
    fapx *h = NULL;
    CHECK_EQ(fapx_open(&h, t.name, &fo), 0);
    CHECK_EQ(wait_rt_threads(SCHED_FIFO, 12, 1), 1);
    CHECK_EQ(seen_self().policy, SCHED_OTHER);
    fapx_close(h);
    CHECK_EQ(rt_threads(SCHED_FIFO, 12), 0);
    close(t.master);

    /* exec async slave: the thread that serves */
    MUST(tp_open(&t) == 0);
    fap_port_options po = pty_opts("rr:13");
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    struct serve_arg a = {NULL, 1, {0, 0, 0}};
    MUST(execSlaveOpen(&a.s, t.name, &po, &so, serve_handler, NULL) == 0);
    pthread_t th;
    MUST(pthread_create(&th, NULL, serve_main, &a) == 0);
    pthread_join(th, NULL);
    CHECK_EQ(a.rc, 0);   /* nothing came within 0 ms */
    CHECK_EQ(a.after.policy, SCHED_RR);
    CHECK_EQ(a.after.priority, 13);
    CHECK_EQ(seen_self().policy, SCHED_OTHER);
    execSlaveClose(a.s);
    close(t.master);

    /* the classic API: FAP_REALTIME, the engine thread fapConfig starts */
    MUST(tp_open(&t) == 0);
    setenv("FAP_REALTIME", "fifo:15", 1);
    CHECK(fapInit(t.name, 115200) == GOOD);
    unsetenv("FAP_REALTIME");
    fapT cfg = {.id = 0, .mode = FAP_MASTER, .idcTime = 0};
    CHECK(fapConfig(&cfg) == GOOD);
    CHECK_EQ(wait_rt_threads(SCHED_FIFO, 15, 1), 1);
    fapClassicClose();
    CHECK_EQ(rt_threads(SCHED_FIFO, 15), 0);
    close(t.master);

    /* the virtual bus relay */
    fap_vbus_options vo;
    fap_vbus_options_init(&vo);
    vo.baud = 115200;
    vo.rt = spec("fifo:14");
    fap_vbus *bus = NULL;
    CHECK_EQ(fap_vbus_open(&bus, &vo), 0);
    CHECK_EQ(rt_threads(SCHED_FIFO, 14), 1);   /* open waits for the relay's apply */
    fap_vbus_close(bus);
}

/* ---- refusals, in a child that lost the privilege ---------------------- */

/* RLIMIT_RTPRIO at rtprio (lowered to the hard limit: raising it needs
 * CAP_SYS_RESOURCE, which a container may lack), RLIMIT_MEMLOCK 0, then
 * CAP_SYS_NICE and CAP_IPC_LOCK gone. Returns 0 or -errno; *got = the
 * RTPRIO limit now in force. */
static int drop_privilege(rlim_t rtprio, rlim_t *got)
{
    struct rlimit rl;
    if (getrlimit(RLIMIT_RTPRIO, &rl) < 0)
        return -errno;
    if (rl.rlim_max != RLIM_INFINITY && rtprio > rl.rlim_max)
        rtprio = rl.rlim_max;
    rl.rlim_cur = rl.rlim_max = rtprio;
    struct rlimit zero = {0, 0};
    if (setrlimit(RLIMIT_RTPRIO, &rl) < 0 || setrlimit(RLIMIT_MEMLOCK, &zero) < 0)
        return -errno;
    *got = rtprio;
    struct __user_cap_header_struct hdr = {_LINUX_CAPABILITY_VERSION_3, 0};
    struct __user_cap_data_struct data[2];
    if (syscall(SYS_capget, &hdr, data) < 0)
        return -errno;
    for (int i = 0; i < 2; i++) {
        uint32_t drop = 0;
        if (CAP_SYS_NICE / 32 == i)
            drop |= 1u << (CAP_SYS_NICE % 32);
        if (CAP_IPC_LOCK / 32 == i)
            drop |= 1u << (CAP_IPC_LOCK % 32);
        data[i].effective &= ~drop;
        data[i].permitted &= ~drop;
        data[i].inheritable &= ~drop;
    }
    if (syscall(SYS_capset, &hdr, data) < 0)
        return -errno;
    return 0;
}

static void refused_in_child(void)
{
    rlim_t rtprio = 0;
    int dropped = drop_privilege(20, &rtprio);
    if (dropped)
        fprintf(stderr, "drop_privilege: %s\n", strerror(-dropped));
    MUST(dropped == 0);
    fap_port_rt rt = {FAP_RT_FIFO, 10, 0, 0};
    if (rtprio >= 10)
        CHECK_EQ(fap_port_rt_check(&rt), 0);          /* RLIMIT_RTPRIO 20 allows 10 */
    else
        fprintf(stderr, "note: RLIMIT_RTPRIO hard limit %ld: the rlimit grant is not "
                        "tried\n", (long)rtprio);
    rt.priority = 30;
    CHECK_EQ(fap_port_rt_apply(&rt), FAP_PORT_ERTPRIV);   /* ... but not 30 */
    CHECK_EQ(fap_port_rt_check(&rt), FAP_PORT_ERTPRIV);
    rt = (fap_port_rt){FAP_RT_OFF, 0, 1, 0};
    if (!SANITIZED)   /* the sanitizers' mlockall is a no-op that says 0 */
        CHECK_EQ(fap_port_rt_apply(&rt), FAP_PORT_EMLOCK);
    CHECK(strstr(fap_port_strerror(FAP_PORT_ERTPRIV), "CAP_SYS_NICE") != NULL);
    CHECK(strstr(fap_port_strerror(FAP_PORT_EMLOCK), "mlockall") != NULL);

    /* every engine's open fails with the code, and nothing stays open */
    test_pty t;
    MUST(tp_open(&t) == 0);
    fap_port_options po = pty_opts("fifo:30");
    fap_port *p = NULL;
    CHECK_EQ(fap_port_open(&p, t.name, &po), FAP_PORT_ERTPRIV);
    CHECK(p == NULL);
    fapx_options fo;
    fapx_options_init(&fo);
    fo.mode = FAPX_MASTER;
    fo.port = po;
    fapx *h = NULL;
    CHECK_EQ(fapx_open(&h, t.name, &fo), FAP_PORT_ERTPRIV);
    CHECK(h == NULL);
    execSlaveOptions so;
    execSlaveOptionsInit(&so);
    execSlave *s = NULL;
    CHECK_EQ(execSlaveOpen(&s, t.name, &po, &so, serve_handler, NULL), FAP_PORT_ERTPRIV);
    po.rt = spec("mlock");
    if (!SANITIZED)
        CHECK_EQ(fap_port_open(&p, t.name, &po), FAP_PORT_EMLOCK);
    fap_vbus_options vo;
    fap_vbus_options_init(&vo);
    vo.rt = spec("rr:50");
    fap_vbus *bus = NULL;
    CHECK_EQ(fap_vbus_open(&bus, &vo), FAP_PORT_ERTPRIV);
    CHECK(bus == NULL);
    /* the classic API: FAP_REALTIME */
    setenv("FAP_REALTIME", "fifo:40", 1);
    CHECK(fapInit(t.name, 115200) == BAD);
    setenv("FAP_REALTIME", "fifo:x", 1);
    CHECK(fapInit(t.name, 115200) == BAD);
    if (rtprio >= 5) {
        setenv("FAP_REALTIME", "fifo:5", 1);   /* within RLIMIT_RTPRIO */
        CHECK(fapInit(t.name, 115200) == GOOD);
        fapClassicClose();
    }
    setenv("FAP_REALTIME", "", 1);   /* empty: off */
    CHECK(fapInit(t.name, 115200) == GOOD);
    fapClassicClose();
    unsetenv("FAP_REALTIME");
    po.rt = spec("");
    CHECK_EQ(fap_port_open(&p, t.name, &po), 0);   /* without the option: fine */
    fap_port_close(p);
    close(t.master);
}

/* Run fn in a child (what it drops stays there); its checks pass or not. */
static void in_child(void (*fn)(void))
{
    fflush(NULL);
    pid_t pid = fork();
    REQUIRE(pid >= 0);
    if (pid == 0) {
        fn();
        fflush(NULL);
        _exit(unit_failed ? 1 : 0);
    }
    int status = 0;
    REQUIRE(waitpid(pid, &status, 0) == pid);
    CHECK(WIFEXITED(status) && WEXITSTATUS(status) == 0);
}

static void test_refused(void)
{
    in_child(refused_in_child);
}

/* Checked at open, refused when the engine thread starts (the privilege
 * went away in between): counted in the port's rt_refused, not lost. */
static void refused_after_open_in_child(void)
{
    test_pty t;
    MUST(tp_open(&t) == 0);
    setenv("FAP_REALTIME", "fifo:10", 1);
    MUST(fapInit(t.name, 115200) == GOOD);
    rlim_t rtprio;
    MUST(drop_privilege(0, &rtprio) == 0);   /* threads made from now on inherit it */
    fapT cfg = {.id = 0, .mode = FAP_MASTER, .idcTime = 0};
    CHECK(fapConfig(&cfg) == GOOD);
    fap_port_stats st = {0};
    int64_t end = tp_now_ns() + 5000000000LL;
    do {
        fap_port_get_stats(fapx_port(fapClassicHandle()), &st);
    } while (st.rt_refused == 0 && tp_now_ns() < end && sched_yield() == 0);
    CHECK_EQ(st.rt_refused, 1);
    CHECK_EQ(rt_threads(SCHED_FIFO, 10), 0);
    fapClassicClose();
    close(t.master);
}

static void test_refused_after_open(void)
{
    if (privileged())
        in_child(refused_after_open_in_child);
}

static void test_mlock(void)
{
    if (SANITIZED) {   /* the sanitizer's shadow memory cannot be locked */
        fprintf(stderr, "note: mlockall not tried under a sanitizer\n");
        return;
    }
    fflush(NULL);
    pid_t pid = fork();
    REQUIRE(pid >= 0);
    if (pid == 0) {   /* a child: the lock is process-wide */
        fap_port_rt rt = spec("mlock");
        int ok = fap_port_rt_check(&rt) == 0;
        FILE *f = fopen("/proc/self/status", "r");
        char line[256];
        long kb = -1;
        while (f && fgets(line, sizeof line, f))
            if (sscanf(line, "VmLck: %ld", &kb) == 1)
                break;
        if (f)
            fclose(f);
        _exit(ok && kb > 0 ? 0 : 1);
    }
    int status = 0;
    REQUIRE(waitpid(pid, &status, 0) == pid);
    CHECK(WIFEXITED(status) && WEXITSTATUS(status) == 0);
}

UNIT_MAIN(UNIT(test_parse), UNIT(test_env), UNIT(test_apply_in_thread), UNIT(test_bad_cpu),
          UNIT(test_port_enter), UNIT(test_engines), UNIT(test_refused),
          UNIT(test_refused_after_open), UNIT(test_mlock))
