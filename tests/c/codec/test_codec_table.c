/* The codec table (include/fap_codec.h), through the shared library: every
 * row found by name and by index; the vectors of tests/vectors decoded
 * through it (fields, raw bytes, reject reasons); a vector stream fed
 * all at once, byte by byte and in odd chunks reports the same; the exec
 * and mikroC reports tile the stream; FAP's gap and every codec's end of
 * input. */
#include <stdint.h>
#include <stdlib.h>

#include "fap_codec.h"
#include "json_scan.h"
#include "unit.h"

/* ---- a log of the reports, one text line each ---- */
typedef struct logbuf {
    const fap_codec *c;
    char text[1 << 16];
    size_t len;
    int frames, rejects, garbage;
    uint64_t covered;          /* end of the last report (tiling check) */
    int tiles;                 /* every report started where the previous ended */
} logbuf;

static void put(logbuf *l, const char *s)
{
    size_t n = strlen(s);
    if (l->len + n < sizeof l->text) {
        memcpy(l->text + l->len, s, n + 1);
        l->len += n;
    }
}

static void put_hex(logbuf *l, const uint8_t *p, size_t n)
{
    char h[3];
    for (size_t i = 0; i < n; i++) {
        snprintf(h, sizeof h, "%02x", p[i]);
        put(l, h);
    }
}

static void span(logbuf *l, uint64_t off, size_t n)
{
    if (off != l->covered)
        l->tiles = 0;
    l->covered = off + n;
}

static void on_frame(void *ctx, const fap_codec_frame *f)
{
    logbuf *l = ctx;
    char s[128];
    l->frames++;
    span(l, f->offset, f->raw_len);
    snprintf(s, sizeof s, "F %llu", (unsigned long long)f->offset);
    put(l, s);
    for (unsigned i = 0; i < l->c->n_fields; i++) {
        snprintf(s, sizeof s, " %s=%u", l->c->field_names[i], f->field[i]);
        put(l, s);
    }
    put(l, " data=");
    put_hex(l, f->data, f->data_len);
    put(l, " raw=");
    put_hex(l, f->raw, f->raw_len);
    put(l, "\n");
}

static void on_reject(void *ctx, int code, const uint8_t *raw, size_t n, uint64_t offset)
{
    logbuf *l = ctx;
    char s[96];
    if (code == FAP_CODEC_GARBAGE)
        l->garbage++;
    else
        l->rejects++;
    span(l, offset, n);
    snprintf(s, sizeof s, "R %s %llu ", l->c->reject_name(code), (unsigned long long)offset);
    put(l, s);
    put_hex(l, raw, n);
    put(l, "\n");
}

static void log_init(logbuf *l, const fap_codec *c)
{
    memset(l, 0, sizeof *l);
    l->c = c;
    l->tiles = 1;
}

/* Feed p in chunks of `chunk` bytes (0: all at once), then finish. */
static void decode(logbuf *l, const fap_codec *c, const uint8_t *p, size_t n, size_t chunk)
{
    void *st = malloc(c->state_size);
    c->init(st, 115200, 0);
    size_t step = chunk ? chunk : (n ? n : 1);
    for (size_t at = 0; at < n; at += step)
        c->feed(st, p + at, n - at < step ? n - at : step, 1000, on_frame, on_reject, l);
    c->finish(st, on_frame, on_reject, l);
    free(st);
}

/* ---- the vectors: each row's rows/<name>.row (rows/README) ---- */
typedef struct proto {
    char vectors[512];
    char keys[FAP_CODEC_MAX_FIELDS][32];   /* the vector file's names of the fields */
    int tiles;
    uint8_t partial[64];                   /* garbage then a partial frame (optional) */
    size_t partial_len;
} proto;

#ifndef LF_CODEC_N_ROWS
#error "LF_CODEC_N_ROWS: the rows of the table, from csrc/meson.build (tests/c/codec/meson.build)"
#endif

/* Read rows/<name>.row of row c; 0 when it is missing. */
static int proto_load(const fap_codec *c, proto *p)
{
    char path[512], line[512];
    memset(p, 0, sizeof *p);
    snprintf(path, sizeof path, "%s/%s.row", getenv("CODEC_ROWS_DIR"), c->name);
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "codec row %s: no %s\n", c->name, path);
        return 0;
    }
    while (fgets(line, sizeof line, f)) {
        char key[32], val[400];
        if (line[0] == '#' || sscanf(line, "%31s %399[^\n]", key, val) != 2)
            continue;
        if (!strcmp(key, "vectors"))
            snprintf(p->vectors, sizeof p->vectors, "%s/%s", getenv("SOURCE_ROOT"), val);
        else if (!strcmp(key, "keys"))
            sscanf(val, "%31s %31s %31s %31s", p->keys[0], p->keys[1], p->keys[2], p->keys[3]);
        else if (!strcmp(key, "tiles"))
            p->tiles = !strcmp(val, "yes");
        else if (!strcmp(key, "partial"))
            p->partial_len = unit_unhex(val, p->partial, sizeof p->partial);
    }
    fclose(f);
    return p->vectors[0] != 0;
}

static long js_num(const char *v)
{
    if (!v)
        return -1;
    if (!strncmp(v, "true", 4))
        return 1;
    if (!strncmp(v, "false", 5))
        return 0;
    return strtol(v, NULL, 10);
}

typedef struct vec_ctx {
    const proto *p;
    const fap_codec *c;
    int valid;
    uint8_t stream[1 << 14];
    size_t n;
    int count;
    char reasons[256];          /* the invalid vectors' reasons, space separated */
} vec_ctx;

static const uint8_t GARBAGE[] = {0x00, 0x01, 0x55};   /* starts no frame of any protocol */

static int one_vector(const char *obj, const char *end, void *ctx_)
{
    vec_ctx *v = ctx_;
    uint8_t frame[2048], data[1100];
    char name[96], reason[32];
    size_t fn = js_hex(js_field(obj, end, "frame"), frame, sizeof frame);
    js_string(js_field(obj, end, "name"), name, sizeof name);
    logbuf *l = malloc(sizeof *l);
    log_init(l, v->c);
    decode(l, v->c, frame, fn, 0);
    if (v->valid) {
        size_t dn = js_hex(js_field(obj, end, "data"), data, sizeof data);
        char want[4096];
        int k = snprintf(want, sizeof want, "F 0");
        for (unsigned i = 0; i < v->c->n_fields; i++)
            k += snprintf(want + k, sizeof want - (size_t)k, " %s=%ld", v->c->field_names[i],
                          js_num(js_field(obj, end, v->p->keys[i])));
        logbuf *w = malloc(sizeof *w);
        log_init(w, v->c);
        put(w, want);
        put(w, " data=");
        put_hex(w, data, dn);
        put(w, " raw=");
        put_hex(w, frame, fn);
        put(w, "\n");
        if (strcmp(l->text, w->text) != 0)
            fprintf(stderr, "%s: got\n%swant\n%s", name, l->text, w->text);
        CHECK(strcmp(l->text, w->text) == 0);
        free(w);
        /* the row's encoder writes the vector's frame from its fields */
        unsigned fields[FAP_CODEC_MAX_FIELDS] = {0};
        for (unsigned i = 0; i < v->c->n_fields; i++)
            fields[i] = (unsigned)js_num(js_field(obj, end, v->p->keys[i]));
        uint8_t enc[2048];
        CHECK(v->c->max_frame <= sizeof enc);
        CHECK_EQ(v->c->encode(enc, sizeof enc, fields, data, dn), fn);
        CHECK_MEM(enc, frame, fn);
        CHECK_EQ(v->c->encode(enc, v->c->max_frame - 1 < fn ? v->c->max_frame - 1 : fn - 1,
                              fields, data, dn), 0);
    } else {
        js_string(js_field(obj, end, "reason"), reason, sizeof reason);
        char want[64];
        snprintf(want, sizeof want, "R %s 0 ", reason);
        CHECK_EQ(l->frames, 0);
        CHECK(strncmp(l->text, want, strlen(want)) == 0);
        if (strncmp(l->text, want, strlen(want)) != 0)
            fprintf(stderr, "%s: got\n%s", name, l->text);
        strncat(v->reasons, reason, sizeof v->reasons - strlen(v->reasons) - 2);
        strcat(v->reasons, " ");
    }
    free(l);
    if (v->n + fn + sizeof GARBAGE < sizeof v->stream) {
        memcpy(v->stream + v->n, frame, fn);
        v->n += fn;
        memcpy(v->stream + v->n, GARBAGE, sizeof GARBAGE);
        v->n += sizeof GARBAGE;
    }
    v->count++;
    return 1;
}

static void test_table(void)
{
    size_t n = 0;
    const fap_codec *c;
    for (; (c = fap_codec_at(n)) != NULL; n++) {
        CHECK(fap_codec_find(c->name) == c);
        CHECK(c->state_size > 0 && c->n_fields > 0 && c->n_fields <= FAP_CODEC_MAX_FIELDS);
        CHECK(c->init && c->feed && c->deadline && c->tick && c->finish && c->reject_name &&
              c->frame_name && c->missing && c->encode && c->max_frame > 0);
        unsigned bad[FAP_CODEC_MAX_FIELDS] = {256, 256, 256, 256};
        uint8_t out[2048];
        CHECK_EQ(c->encode(out, sizeof out, bad, NULL, 0), 0);
        CHECK_EQ(strcmp(c->reject_name(FAP_CODEC_GARBAGE), "garbage"), 0);
        CHECK_EQ(strcmp(c->reject_name(FAP_CODEC_TRUNCATED), "truncated"), 0);
        CHECK_EQ(strcmp(c->reject_name(-12345), "?"), 0);
    }
    CHECK_EQ(n, LF_CODEC_N_ROWS);          /* the generated table has every row */
    CHECK(fap_codec_find("execasync") == fap_codec_find("exec"));
    CHECK(fap_codec_find(NULL) == NULL);
    CHECK(fap_codec_find("modbus") == NULL);
    CHECK(fap_codec_find("") == NULL);
}

/* The same frames and rejects in the same order; garbage is reported as
 * it comes, so its runs depend on the chunking and are skipped here. */
static int same_reports(const char *a, const char *b)
{
    for (;;) {
        while (!strncmp(a, "R garbage", 9))
            a = strchr(a, '\n') + 1;
        while (!strncmp(b, "R garbage", 9))
            b = strchr(b, '\n') + 1;
        if (!*a || !*b)
            return !*a && !*b;
        size_t la = strcspn(a, "\n"), lb = strcspn(b, "\n");
        if (la != lb || strncmp(a, b, la) != 0) {
            fprintf(stderr, "differ:\n%.*s\n%.*s\n", (int)la, a, (int)lb, b);
            return 0;
        }
        a += la + 1;
        b += lb + 1;
    }
}

/* The vectors one by one, then all in a stream with garbage between. */
static void test_vectors(void)
{
    const fap_codec *c;
    for (size_t i = 0; (c = fap_codec_at(i)) != NULL; i++) {
        proto *p = malloc(sizeof *p);
        REQUIRE(proto_load(c, p));
        char *doc = js_slurp(p->vectors);
        REQUIRE(doc != NULL);
        vec_ctx *v = calloc(1, sizeof *v);
        v->p = p;
        v->c = c;
        memcpy(v->stream, GARBAGE, sizeof GARBAGE);
        v->n = sizeof GARBAGE;
        v->valid = 1;
        size_t nv = js_each(doc, "valid", one_vector, v);
        v->valid = 0;
        size_t ni = js_each(doc, "invalid", one_vector, v);
        CHECK(nv > 0 && ni > 0);

        /* the stream: the same reports whatever the chunking */
        logbuf *whole = malloc(sizeof *whole), *other = malloc(sizeof *other);
        log_init(whole, v->c);
        decode(whole, v->c, v->stream, v->n, 0);
        CHECK_EQ(whole->frames, nv);
        CHECK_EQ(whole->rejects, ni);          /* each bad vector rejected once */
        if (p->tiles)
            CHECK(whole->tiles && whole->covered == v->n);
        static const size_t chunks[] = {1, 2, 7, 64};
        for (size_t k = 0; k < sizeof chunks / sizeof chunks[0]; k++) {
            log_init(other, v->c);
            decode(other, v->c, v->stream, v->n, chunks[k]);
            CHECK(same_reports(whole->text, other->text));
            if (p->tiles)
                CHECK(other->tiles && other->covered == v->n);
        }
        free(whole);
        free(other);
        free(v);
        free(doc);
        free(p);
    }
}

/* FAP's inter-byte gap: tick before the deadline keeps the partial frame,
 * after it rejects it ("gap"); finish calls a held partial "truncated". */
static void test_fap_gap_and_finish(void)
{
    const fap_codec *c = fap_codec_find("fap");
    void *st = malloc(c->state_size);
    static const uint8_t part[] = "cCtRsFeF\x0d\x00";
    logbuf *l = malloc(sizeof *l);
    log_init(l, c);
    c->init(st, 0, 1000000);
    CHECK(c->deadline(st) == FAP_CODEC_NEVER);
    c->feed(st, part, 10, 5000000, on_frame, on_reject, l);
    CHECK_EQ(c->deadline(st), 6000000);
    CHECK_EQ(c->missing(st), 5);
    c->tick(st, 5999999, on_frame, on_reject, l);
    CHECK_EQ(l->len, 0);
    c->tick(st, 6000000, on_frame, on_reject, l);
    CHECK(!strncmp(l->text, "R gap 0 634374527346654", 23));
    CHECK(c->deadline(st) == FAP_CODEC_NEVER);
    log_init(l, c);
    c->feed(st, part, 10, 7000000, on_frame, on_reject, l);
    c->finish(st, on_frame, on_reject, l);
    CHECK(!strncmp(l->text, "R truncated 10 ", 15));
    CHECK(c->deadline(st) == FAP_CODEC_NEVER);
    free(l);
    free(st);
}

/* Rows with a "partial" sample (rows/<name>.row): a partial frame at the
 * end is truncated; tick shows the garbage held back; the offsets run on
 * after finish. */
static void test_span_codecs_end(void)
{
    const fap_codec *c;
    int tried = 0;
    for (size_t i = 0; (c = fap_codec_at(i)) != NULL; i++) {
        proto *p = malloc(sizeof *p);
        REQUIRE(proto_load(c, p));
        if (!p->partial_len) {
            free(p);
            continue;
        }
        tried++;
        void *st = malloc(c->state_size);
        logbuf *l = malloc(sizeof *l);
        log_init(l, c);
        c->init(st, 9600, 0);
        c->feed(st, p->partial, p->partial_len, 1, on_frame, on_reject, l);
        CHECK_EQ(l->garbage, 1);
        CHECK(c->deadline(st) == FAP_CODEC_NEVER);
        CHECK(c->missing(st) > 0);
        c->tick(st, 2, on_frame, on_reject, l);
        c->finish(st, on_frame, on_reject, l);
        CHECK_EQ(l->rejects, 1);
        CHECK(strstr(l->text, "R truncated") != NULL);
        CHECK(l->tiles && l->covered == p->partial_len);
        /* a new stream continues the offsets */
        c->feed(st, GARBAGE, sizeof GARBAGE, 3, on_frame, on_reject, l);
        c->tick(st, 4, on_frame, on_reject, l);
        CHECK(l->tiles && l->covered == p->partial_len + sizeof GARBAGE);
        free(l);
        free(st);
        free(p);
    }
    CHECK(tried > 0);
}

/* Frame names: FAP's message types; exec has none. */
static void test_frame_names(void)
{
    fap_codec_frame f;
    memset(&f, 0, sizeof f);
    const fap_codec *fap = fap_codec_find("fap");
    f.field[0] = 0;
    CHECK_EQ(strcmp(fap->frame_name(&f), "SEND_DATA"), 0);
    f.field[0] = 4;
    CHECK_EQ(strcmp(fap->frame_name(&f), "ID"), 0);
    f.field[0] = 5;
    CHECK(fap->frame_name(&f) == NULL);
    CHECK(fap_codec_find("exec")->frame_name(&f) == NULL);
}

UNIT_MAIN(UNIT(test_table), UNIT(test_vectors), UNIT(test_fap_gap_and_finish),
          UNIT(test_span_codecs_end), UNIT(test_frame_names))
