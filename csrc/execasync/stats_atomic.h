/* Statistics counters bumped by the engine's thread and read by any other:
 * relaxed atomics, so a reader never races (and tsan agrees). */
#ifndef LF_EXEC_STATS_ATOMIC_H
#define LF_EXEC_STATS_ATOMIC_H

#include <stddef.h>
#include <stdint.h>

#define LF_STAT_INC(field)  __atomic_fetch_add(&(field), 1, __ATOMIC_RELAXED)
#define LF_STAT_LOAD(field) __atomic_load_n(&(field), __ATOMIC_RELAXED)

/* Snapshot a stats struct made only of uint64_t counters (size bytes). */
static inline void lf_stats_load(void *out, const void *stats, size_t size)
{
    const uint64_t *src = stats;
    uint64_t *dst = out;
    for (size_t i = 0; i < size / sizeof(uint64_t); i++)
        dst[i] = LF_STAT_LOAD(src[i]);
}

#endif
