/* Reads tests/vectors/exec_async.json (a copy of the shared vectors) with
 * just enough parsing for its fixed shape: the "valid" entries' node, seq,
 * data and frame, and the "invalid" entries' frame and reason. */
#ifndef EXEC_TEST_VECTORS_H
#define EXEC_TEST_VECTORS_H
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "unit.h"

typedef struct exec_vector {
    char name[64];
    unsigned node, seq;
    uint8_t data[256];
    size_t data_len;
    uint8_t frame[600];
    size_t frame_len;
    char reason[16];          /* invalid entries only */
} exec_vector;

static char *vec_read_file(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *buf = malloc((size_t)n + 1);
    if (buf && fread(buf, 1, (size_t)n, f) != (size_t)n) {
        free(buf);
        buf = NULL;
    }
    if (buf)
        buf[n] = 0;
    fclose(f);
    return buf;
}

/* Value of "key" in [from, to): a string (copied to out) or a number. */
static const char *vec_field(const char *from, const char *to, const char *key,
                             char *out, size_t cap)
{
    char pat[32];
    snprintf(pat, sizeof pat, "\"%s\":", key);
    const char *p = strstr(from, pat);
    if (!p || p >= to)
        return NULL;
    p += strlen(pat);
    while (*p == ' ')
        p++;
    size_t n = 0;
    if (*p == '"') {
        p++;
        while (*p && *p != '"' && n + 1 < cap)
            out[n++] = *p++;
    } else {
        while (*p && *p != ',' && *p != '\n' && *p != '}' && n + 1 < cap)
            out[n++] = *p++;
    }
    out[n] = 0;
    return out;
}

/* Parse the entries of section ("valid" or "invalid"); returns the count. */
static size_t vec_load(const char *text, const char *section, exec_vector *v, size_t max)
{
    char key[32];
    snprintf(key, sizeof key, "\"%s\":", section);
    const char *p = strstr(text, key);
    if (!p)
        return 0;
    const char *end = strchr(p, ']');
    size_t count = 0;
    static char tmp[1200];
    while (count < max) {
        const char *open = strchr(p, '{');
        if (!open || open > end)
            break;
        const char *close = strchr(open, '}');
        exec_vector *e = &v[count];
        memset(e, 0, sizeof *e);
        vec_field(open, close, "name", e->name, sizeof e->name);
        if (vec_field(open, close, "node", tmp, sizeof tmp))
            e->node = (unsigned)atoi(tmp);
        if (vec_field(open, close, "seq", tmp, sizeof tmp))
            e->seq = (unsigned)atoi(tmp);
        if (vec_field(open, close, "data", tmp, sizeof tmp))
            e->data_len = unit_unhex(tmp, e->data, sizeof e->data);
        if (vec_field(open, close, "frame", tmp, sizeof tmp))
            e->frame_len = unit_unhex(tmp, e->frame, sizeof e->frame);
        vec_field(open, close, "reason", e->reason, sizeof e->reason);
        count++;
        p = close + 1;
    }
    return count;
}
#endif
