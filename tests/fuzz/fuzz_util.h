/* Shared by the libFuzzer targets: a cursor over the fuzz input and a
 * property check that aborts (libFuzzer then saves the input). */
#ifndef LF_FUZZ_UTIL_H
#define LF_FUZZ_UTIL_H
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PROPERTY(cond) do { if (!(cond)) { \
    fprintf(stderr, "%s:%d: property failed: %s\n", __FILE__, __LINE__, #cond); abort(); } } while (0)

typedef struct fz { const uint8_t *p; size_t n; } fz;

static inline int fz_more(const fz *f) { return f->n > 0; }
static inline uint8_t fz_u8(fz *f)
{
    if (!f->n)
        return 0;
    f->n--;
    return *f->p++;
}
static inline uint16_t fz_u16(fz *f)
{
    uint16_t lo = fz_u8(f);
    return (uint16_t)(lo | (uint16_t)fz_u8(f) << 8);
}
static inline uint32_t fz_u32(fz *f)
{
    uint32_t lo = fz_u16(f);
    return lo | (uint32_t)fz_u16(f) << 16;
}
/* Up to want bytes (fewer at the end of the input). */
static inline size_t fz_bytes(fz *f, size_t want, const uint8_t **out)
{
    size_t n = want < f->n ? want : f->n;
    *out = f->p;
    f->p += n;
    f->n -= n;
    return n;
}
#endif
