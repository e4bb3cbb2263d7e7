/* Reads tests/vectors/mikroc_rs485.json (path from argv/env) into a table.
 * A tiny scanner for that file's flat layout: two arrays ("valid",
 * "invalid") of flat objects with string, number and boolean fields. */
#ifndef MIKROC_VECTORS_H
#define MIKROC_VECTORS_H
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MV_MAX 64

typedef struct mv_vector {
    char name[96];
    int valid;
    int address;
    int master;
    uint8_t data[8];
    size_t data_len;
    uint8_t frame[16];
    size_t frame_len;
    char reason[32];
} mv_vector;

static char *mv_slurp(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *s = malloc((size_t)n + 1);
    if (s && fread(s, 1, (size_t)n, f) != (size_t)n) {
        free(s);
        s = NULL;
    }
    if (s)
        s[n] = 0;
    fclose(f);
    return s;
}

/* Value text of "key" inside [obj, end): returns pointer past ':' and spaces. */
static const char *mv_field(const char *obj, const char *end, const char *key)
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

static void mv_string(const char *v, char *out, size_t cap)
{
    size_t n = 0;
    if (v && *v == '"') {
        v++;
        while (*v && *v != '"' && n + 1 < cap)
            out[n++] = *v++;
    }
    out[n] = 0;
}

static size_t mv_hex(const char *v, uint8_t *out, size_t cap)
{
    char tmp[64];
    mv_string(v, tmp, sizeof tmp);
    size_t n = 0;
    for (const char *h = tmp; h[0] && h[1] && n < cap; h += 2) {
        unsigned x;
        if (sscanf(h, "%2x", &x) != 1)
            break;
        out[n++] = (uint8_t)x;
    }
    return n;
}

/* Next occurrence of c outside JSON strings (names contain braces). */
static const char *mv_next(const char *p, char c)
{
    int in_str = 0;
    for (; *p; p++) {
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

/* Parse the objects of array `key`; returns how many were added. */
static size_t mv_parse_array(const char *doc, const char *key, int valid,
                             mv_vector *out, size_t have, size_t cap)
{
    const char *a = mv_field(doc, doc + strlen(doc), key);
    if (!a || *a != '[')
        return 0;
    const char *close = mv_next(a, ']');
    size_t n = 0;
    for (const char *o = mv_next(a, '{'); o && close && o < close && have + n < cap;
         o = mv_next(o, '{')) {
        const char *e = mv_next(o, '}');
        if (!e)
            break;
        mv_vector *v = &out[have + n];
        memset(v, 0, sizeof *v);
        v->valid = valid;
        mv_string(mv_field(o, e, "name"), v->name, sizeof v->name);
        v->frame_len = mv_hex(mv_field(o, e, "frame"), v->frame, sizeof v->frame);
        const char *f;
        if ((f = mv_field(o, e, "address")))
            v->address = atoi(f);
        if ((f = mv_field(o, e, "data")))
            v->data_len = mv_hex(f, v->data, sizeof v->data);
        if ((f = mv_field(o, e, "master")))
            v->master = strncmp(f, "true", 4) == 0;
        mv_string(mv_field(o, e, "reason"), v->reason, sizeof v->reason);
        n++;
        o = e;
    }
    return n;
}

/* Load the vectors; the path comes from $MIKROC_VECTORS (set by meson). */
static size_t mv_load(mv_vector *out, size_t cap)
{
    const char *path = getenv("MIKROC_VECTORS");
    char *doc = path ? mv_slurp(path) : NULL;
    if (!doc) {
        fprintf(stderr, "cannot read vectors (MIKROC_VECTORS=%s)\n", path ? path : "unset");
        return 0;
    }
    size_t n = mv_parse_array(doc, "valid", 1, out, 0, cap);
    n += mv_parse_array(doc, "invalid", 0, out, n, cap);
    free(doc);
    return n;
}
#endif
