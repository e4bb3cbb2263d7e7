/* Just enough JSON for the test-vector files in tests/vectors/: flat
 * objects inside named arrays, with string, number and boolean fields.
 * Shared by the C tests that load vectors at run time. */
#ifndef LF_JSON_SCAN_H
#define LF_JSON_SCAN_H
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Whole file as a NUL-terminated string (free() it), or NULL. */
static inline char *js_slurp(const char *path)
{
    FILE *f = path ? fopen(path, "rb") : NULL;
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *s = n >= 0 ? malloc((size_t)n + 1) : NULL;
    if (s && fread(s, 1, (size_t)n, f) != (size_t)n) {
        free(s);
        s = NULL;
    }
    if (s)
        s[n] = 0;
    fclose(f);
    return s;
}

/* Next occurrence of c outside JSON strings (names may hold braces). */
static inline const char *js_next(const char *p, char c)
{
    int in_str = 0;
    for (; p && *p; p++) {
        if (in_str) {
            if (*p == '\\' && p[1])
                p++;
            else if (*p == '"')
                in_str = 0;
        } else if (*p == '"') {
            in_str = 1;
        } else if (*p == c) {
            return p;
        }
    }
    return NULL;
}

/* Start of the value of "key" inside [obj, end), or NULL. */
static inline const char *js_field(const char *obj, const char *end, const char *key)
{
    char pat[48];
    snprintf(pat, sizeof pat, "\"%s\"", key);
    const char *p = strstr(obj, pat);
    if (!p || p >= end)
        return NULL;
    p += strlen(pat);
    while (*p == ' ' || *p == ':' || *p == '\n')
        p++;
    return p;
}

/* Copy a string value (v points at its opening quote); "" if v is NULL. */
static inline void js_string(const char *v, char *out, size_t cap)
{
    size_t n = 0;
    if (v && *v == '"') {
        v++;
        while (*v && *v != '"' && n + 1 < cap)
            out[n++] = *v++;
    }
    out[n] = 0;
}

/* Decode a hex string value into bytes; returns the byte count. */
static inline size_t js_hex(const char *v, uint8_t *out, size_t cap)
{
    size_t n = 0;
    if (!v || *v != '"')
        return 0;
    for (const char *h = v + 1; h[0] != '"' && h[1] != '"' && h[0] && h[1] && n < cap; h += 2) {
        unsigned x;
        if (sscanf(h, "%2x", &x) != 1)
            break;
        out[n++] = (uint8_t)x;
    }
    return n;
}

/* Call fn(obj, end, ctx) for every object of array "key" in doc; returns
 * how many objects were visited (fn returns 0 to stop early). */
static inline size_t js_each(const char *doc, const char *key,
                             int (*fn)(const char *obj, const char *end, void *ctx), void *ctx)
{
    const char *a = js_field(doc, doc + strlen(doc), key);
    if (!a || *a != '[')
        return 0;
    const char *close = js_next(a, ']');
    size_t n = 0;
    for (const char *o = js_next(a, '{'); o && close && o < close; o = js_next(o, '{')) {
        const char *e = js_next(o, '}');
        if (!e)
            break;
        n++;
        if (!fn(o, e, ctx))
            break;
        o = e;
    }
    return n;
}
#endif
