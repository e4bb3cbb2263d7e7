/* Statistics counters bumped by the engine's thread and read by any other:
 * relaxed atomics, so a reader never races (and tsan agrees). */
#ifndef LF_EXEC_STATS_ATOMIC_H
#define LF_EXEC_STATS_ATOMIC_H

#define LF_STAT_INC(field)  __atomic_fetch_add(&(field), 1, __ATOMIC_RELAXED)
#define LF_STAT_LOAD(field) __atomic_load_n(&(field), __ATOMIC_RELAXED)

#endif
