/* port_rt.c - the real-time option of every engine (docs/realtime.md):
 * one spec parser (C, classic API's FAP_REALTIME, Python, CLI), one check
 * at open, one apply at the start of an engine's I/O thread. */
#include "port/port_internal.h"

#include <ctype.h>
#include <limits.h>
#include <pthread.h>
#include <sched.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

static void say(char *why, size_t n, const char *fmt, ...)
{
    if (!why || !n)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(why, n, fmt, ap);
    va_end(ap);
}

/* A decimal in [lo, hi] spanning exactly s[0..len). */
static int parse_uint(const char *s, size_t len, long lo, long hi, long *out)
{
    if (len == 0 || len > 9)
        return -EINVAL;
    long v = 0;
    for (size_t i = 0; i < len; i++) {
        if (!isdigit((unsigned char)s[i]))
            return -EINVAL;
        v = v * 10 + (s[i] - '0');
    }
    if (v < lo || v > hi)
        return -EINVAL;
    *out = v;
    return 0;
}

/* One item of the spec, s[0..len). */
static int parse_item(const char *s, size_t len, fap_port_rt *rt, int *seen_off, char *why,
                      size_t n)
{
    long a, b;
    if (len == 3 && !memcmp(s, "off", 3)) {
        *seen_off = 1;
        return 0;
    }
    if (len == 5 && !memcmp(s, "mlock", 5)) {
        if (rt->mlock)
            goto twice;
        rt->mlock = 1;
        return 0;
    }
    if ((len > 5 && !memcmp(s, "fifo:", 5)) || (len > 3 && !memcmp(s, "rr:", 3))) {
        int fifo = s[0] == 'f';
        size_t skip = fifo ? 5 : 3;
        if (rt->policy != FAP_RT_OFF)
            goto twice;
        if (parse_uint(s + skip, len - skip, 1, 99, &a) < 0) {
            say(why, n, "real-time item '%.*s': the priority must be 1..99", (int)len, s);
            return -EINVAL;
        }
        rt->policy = fifo ? FAP_RT_FIFO : FAP_RT_RR;
        rt->priority = (int)a;
        return 0;
    }
    if (len > 4 && !memcmp(s, "cpu=", 4)) {
        const char *v = s + 4, *end = s + len;
        const char *dash = memchr(v, '-', (size_t)(end - v));
        int bad = dash ? parse_uint(v, (size_t)(dash - v), 0, FAP_RT_MAX_CPUS - 1, &a) < 0 ||
                             parse_uint(dash + 1, (size_t)(end - dash - 1), a,
                                        FAP_RT_MAX_CPUS - 1, &b) < 0
                       : parse_uint(v, (size_t)(end - v), 0, FAP_RT_MAX_CPUS - 1, &a) < 0;
        if (bad) {
            say(why, n, "real-time item '%.*s': want cpu=N or cpu=N-M, CPUs 0..%d", (int)len,
                s, FAP_RT_MAX_CPUS - 1);
            return -EINVAL;
        }
        if (!dash)
            b = a;
        for (long c = a; c <= b; c++)
            rt->cpus |= UINT64_C(1) << c;
        return 0;
    }
    say(why, n, "unknown real-time item '%.*s' (want fifo:PRIO, rr:PRIO, mlock, cpu=N[-M] "
                "or off)", (int)len, s);
    return -EINVAL;
twice:
    say(why, n, "real-time item '%.*s': that kind of item was given already", (int)len, s);
    return -EINVAL;
}

int fap_port_rt_parse(const char *spec, fap_port_rt *out, char *why, size_t n)
{
    fap_port_rt rt = {FAP_RT_OFF, 0, 0, 0};
    int seen_off = 0, items = 0;
    say(why, n, "%s", "");
    if (!out) {
        say(why, n, "no place for the result");
        return -EINVAL;
    }
    const char *s = spec ? spec : "";
    while (*s) {
        const char *comma = strchr(s, ',');
        size_t len = comma ? (size_t)(comma - s) : strlen(s);
        if (len == 0) {
            say(why, n, "empty item in real-time spec '%s'", spec);
            return -EINVAL;
        }
        int err = parse_item(s, len, &rt, &seen_off, why, n);
        if (err)
            return err;
        items++;
        s += len;
        if (*s == ',' && !*++s) {
            say(why, n, "real-time spec '%s' ends with a comma", spec);
            return -EINVAL;
        }
    }
    if (seen_off && items > 1) {
        say(why, n, "real-time spec '%s': 'off' goes alone", spec);
        return -EINVAL;
    }
    *out = rt;
    return 0;
}

int fap_port_rt_from_env(fap_port_rt *out, char *why, size_t n)
{
    const char *spec = getenv("FAP_REALTIME");
    int err = fap_port_rt_parse(spec, out, why, n);
    if (err && why && n) {   /* name where the spec came from */
        char inner[160];
        snprintf(inner, sizeof inner, "%s", why);
        say(why, n, "FAP_REALTIME: %s", inner);
    }
    return err;
}

static int rt_is_off(const fap_port_rt *rt)
{
    return !rt || (rt->policy == FAP_RT_OFF && !rt->mlock && !rt->cpus);
}

static int rt_valid(const fap_port_rt *rt)
{
    if (rt->policy == FAP_RT_OFF)
        return rt->priority == 0 ? 0 : -EINVAL;
    if (rt->policy != FAP_RT_FIFO && rt->policy != FAP_RT_RR)
        return -EINVAL;
    int pol = rt->policy == FAP_RT_FIFO ? SCHED_FIFO : SCHED_RR;
    if (rt->priority < sched_get_priority_min(pol) || rt->priority > sched_get_priority_max(pol))
        return -EINVAL;
    return 0;
}

/* The affinity the kernel keeps is the asked set minus CPUs the process
 * may not use (cpuset, offline): read it back, so a CPU that was dropped
 * is refused rather than quietly left out. */
static int apply_cpus(uint64_t cpus)
{
    cpu_set_t want, got;
    CPU_ZERO(&want);
    for (int c = 0; c < FAP_RT_MAX_CPUS; c++)
        if (cpus & (UINT64_C(1) << c))
            CPU_SET(c, &want);
    int e = pthread_setaffinity_np(pthread_self(), sizeof want, &want);
    if (e == EINVAL)
        return FAP_PORT_ERTCPU;
    if (e)
        return -e;
    e = pthread_getaffinity_np(pthread_self(), sizeof got, &got);
    if (e)
        return -e;
    return CPU_EQUAL(&want, &got) ? 0 : FAP_PORT_ERTCPU;
}

int fap_port_rt_apply(const fap_port_rt *rt)
{
    if (rt && rt_valid(rt) < 0)
        return -EINVAL;
    if (rt_is_off(rt))
        return 0;
    if (rt->mlock && mlockall(MCL_CURRENT | MCL_FUTURE) < 0)
        return errno == ENOMEM || errno == EPERM || errno == EAGAIN ? FAP_PORT_EMLOCK : -errno;
    if (rt->cpus) {
        int err = apply_cpus(rt->cpus);
        if (err)
            return err;
    }
    if (rt->policy != FAP_RT_OFF) {
        struct sched_param sp = {.sched_priority = rt->priority};
        int pol = rt->policy == FAP_RT_FIFO ? SCHED_FIFO : SCHED_RR;
        int e = pthread_setschedparam(pthread_self(), pol, &sp);
        if (e == EPERM)
            return FAP_PORT_ERTPRIV;
        if (e)
            return -e;
    }
    return 0;
}

struct rt_try {
    const fap_port_rt *rt;
    int result;
};

static void *rt_try_main(void *arg)
{
    struct rt_try *t = arg;
    t->result = fap_port_rt_apply(t->rt);
    return NULL;
}

int fap_port_rt_check(const fap_port_rt *rt)
{
    if (rt && rt_valid(rt) < 0)
        return -EINVAL;
    if (rt_is_off(rt))
        return 0;
    struct rt_try t = {rt, 0};
    pthread_t th;
    int e = pthread_create(&th, NULL, rt_try_main, &t);
    if (e)
        return -e;
    pthread_join(th, NULL);
    return t.result;
}

/* Each open gets a serial: a thread remembers the last port it applied
 * for, so a later port at the same address is never taken for it. */
static uint64_t g_rt_serial;
static __thread uint64_t t_rt_applied;

int lf_port_rt_open(fap_port *p)
{
    int err = fap_port_rt_check(&p->opt.rt);
    if (err)
        return err;
    p->rt_serial = __atomic_add_fetch(&g_rt_serial, 1, __ATOMIC_RELAXED);
    return 0;
}

int fap_port_rt_enter(fap_port *p)
{
    if (!p)
        return -EINVAL;
    if (rt_is_off(&p->opt.rt) || t_rt_applied == p->rt_serial)
        return 0;
    int err = fap_port_rt_apply(&p->opt.rt);
    if (err) {
        pthread_mutex_lock(&p->st_mu);
        p->stats.rt_refused++;
        pthread_mutex_unlock(&p->st_mu);
        return err;
    }
    t_rt_applied = p->rt_serial;
    return 0;
}

const char *lf_port_rt_strerror(int err)
{
    switch (err) {
    case FAP_PORT_ERTPRIV:
        return "real-time scheduling refused: needs CAP_SYS_NICE or an RLIMIT_RTPRIO "
               "at least the priority (docs/realtime.md)";
    case FAP_PORT_ERTCPU:
        return "real-time CPU affinity refused: a CPU asked for is not available to "
               "this process";
    case FAP_PORT_EMLOCK:
        return "mlockall refused: needs CAP_IPC_LOCK or a large enough RLIMIT_MEMLOCK, "
               "and the memory";
    default:
        return NULL;
    }
}
