/* Reads tests/vectors/exec_async.json (a copy of the shared vectors): the
 * "valid" entries' node, seq, data and frame, and the "invalid" entries'
 * frame and reason. Parsing is tests/c/json_scan.h's. */
#ifndef EXEC_TEST_VECTORS_H
#define EXEC_TEST_VECTORS_H
#include "json_scan.h"
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

#define vec_read_file js_slurp

typedef struct { exec_vector *v; size_t count, max; } vec_ctx;

static int vec_take(const char *o, const char *e, void *arg)
{
    vec_ctx *c = arg;
    if (c->count >= c->max)
        return 0;
    exec_vector *x = &c->v[c->count++];
    memset(x, 0, sizeof *x);
    const char *f;
    js_string(js_field(o, e, "name"), x->name, sizeof x->name);
    if ((f = js_field(o, e, "node")))
        x->node = (unsigned)atoi(f);
    if ((f = js_field(o, e, "seq")))
        x->seq = (unsigned)atoi(f);
    x->data_len = js_hex(js_field(o, e, "data"), x->data, sizeof x->data);
    x->frame_len = js_hex(js_field(o, e, "frame"), x->frame, sizeof x->frame);
    js_string(js_field(o, e, "reason"), x->reason, sizeof x->reason);
    return 1;
}

/* Parse the entries of section ("valid" or "invalid"); returns the count. */
static size_t vec_load(const char *text, const char *section, exec_vector *v, size_t max)
{
    vec_ctx c = { v, 0, max };
    js_each(text, section, vec_take, &c);
    return c.count;
}
#endif
