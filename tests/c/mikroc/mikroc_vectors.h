/* Reads tests/vectors/mikroc_rs485.json (path from $MIKROC_VECTORS, set by
 * meson) into a table: the "valid" and "invalid" arrays. Parsing is
 * tests/c/json_scan.h's. */
#ifndef MIKROC_VECTORS_H
#define MIKROC_VECTORS_H
#include "json_scan.h"

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

typedef struct { mv_vector *out; size_t n, cap; int valid; } mv_ctx;

static int mv_take(const char *o, const char *e, void *arg)
{
    mv_ctx *c = arg;
    if (c->n >= c->cap)
        return 0;
    mv_vector *v = &c->out[c->n++];
    memset(v, 0, sizeof *v);
    v->valid = c->valid;
    js_string(js_field(o, e, "name"), v->name, sizeof v->name);
    v->frame_len = js_hex(js_field(o, e, "frame"), v->frame, sizeof v->frame);
    v->data_len = js_hex(js_field(o, e, "data"), v->data, sizeof v->data);
    const char *f;
    if ((f = js_field(o, e, "address")))
        v->address = atoi(f);
    if ((f = js_field(o, e, "master")))
        v->master = strncmp(f, "true", 4) == 0;
    js_string(js_field(o, e, "reason"), v->reason, sizeof v->reason);
    return 1;
}

/* Load the vectors; returns how many (valid first, then invalid). */
static size_t mv_load(mv_vector *out, size_t cap)
{
    const char *path = getenv("MIKROC_VECTORS");
    char *doc = js_slurp(path);
    if (!doc) {
        fprintf(stderr, "cannot read vectors (MIKROC_VECTORS=%s)\n", path ? path : "unset");
        return 0;
    }
    mv_ctx c = { out, 0, cap, 1 };
    js_each(doc, "valid", mv_take, &c);
    c.valid = 0;
    js_each(doc, "invalid", mv_take, &c);
    free(doc);
    return c.n;
}
#endif
