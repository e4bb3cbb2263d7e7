/* What the rows of the codec table (include/fap_codec.h) share: the row
 * macros, the common names, and the held stream bytes of a span-reporting
 * scanner, which has not reported them yet. The exec and mikroC scanners report a
 * frame as a span of stream offsets [start, end); this keeps the bytes
 * from the first unreported one on, so every report carries its raw
 * bytes, and reports the bytes before a span as garbage: the reports tile
 * the stream. Sans-I/O. */
#ifndef LF_CODEC_SPAN_H
#define LF_CODEC_SPAN_H
#include <stddef.h>
#include <stdint.h>

#include "fap_codec.h"

/* Room for the longest span a scanner reports (an exec frame cut off at
 * its overflow: 518 bytes) plus one chunk's look-ahead; a longer run is
 * cut as garbage (it starts no frame the scanners would report). */
#define LF_CODEC_SPAN_MAX 2048

typedef struct lf_codec_span {
    uint8_t buf[LF_CODEC_SPAN_MAX];
    uint64_t base;              /* stream offset of buf[0]: all before is reported */
    size_t n;                   /* bytes held */
} lf_codec_span;

/* The callbacks of one feed/tick/finish call. */
typedef struct lf_codec_sink {
    fap_codec_frame_cb on_frame;
    fap_codec_reject_cb on_reject;
    void *ctx;
} lf_codec_sink;

void lf_codec_span_init(lf_codec_span *s, uint64_t base);
/* Hold n more bytes (the first at offset base + held); bytes before
 * offset `free_before` start no frame and are reported as garbage when
 * room is needed. */
void lf_codec_span_push(lf_codec_span *s, const uint8_t *p, size_t n, uint64_t free_before,
                        const lf_codec_sink *k);
/* Report the held bytes before offset upto as one garbage run. */
void lf_codec_span_garbage(lf_codec_span *s, uint64_t upto, const lf_codec_sink *k);
/* Report [start, end) as a reject with code (garbage before it first). */
void lf_codec_span_reject(lf_codec_span *s, uint64_t start, uint64_t end, int code,
                          const lf_codec_sink *k);
/* Report [f->offset, end) as the good frame f (garbage before it first):
 * fills f->raw/raw_len from the held bytes. */
void lf_codec_span_frame(lf_codec_span *s, fap_codec_frame *f, uint64_t end,
                         const lf_codec_sink *k);
/* End of input: the partial frame [start, pos) (if in_frame) is truncated,
 * the rest up to pos garbage. */
void lf_codec_span_end(lf_codec_span *s, int in_frame, uint64_t start, uint64_t pos,
                       const lf_codec_sink *k);

/* Shared by rows: no gap rule (deadline), no message type names, and the
 * names of the codes every row shares (NULL for a row's own code). */
int64_t lf_codec_never(const void *state);
const char *lf_codec_unnamed(const fap_codec_frame *f);
const char *lf_codec_shared_name(int code);

/* <p>_tick of a row without a gap rule: a quiet line brings nothing new,
 * so it is a feed of no bytes (which reports the garbage known so far). */
#define LF_CODEC_TICK_BY_FEED(p)                                                   \
    static void p##_tick(void *state, int64_t now_ns, fap_codec_frame_cb on_frame, \
                         fap_codec_reject_cb on_reject, void *ctx)                 \
    {                                                                              \
        p##_feed(state, NULL, 0, now_ns, on_frame, on_reject, ctx);                \
    }

/* A row's table entry from its functions named <p>_init, <p>_feed ...,
 * its <p>_state type and its <p>_fields names. */
#define LF_CODEC_ROW(p, deadline_, frame_name_, max_frame_) {                        \
    .name = #p, .state_size = sizeof(p##_state),                                     \
    .n_fields = sizeof p##_fields / sizeof p##_fields[0], .field_names = p##_fields, \
    .init = p##_init, .feed = p##_feed, .deadline = deadline_, .tick = p##_tick,     \
    .finish = p##_finish, .reject_name = p##_reject_name, .frame_name = frame_name_, \
    .missing = p##_missing, .encode = p##_encode, .max_frame = max_frame_,          \
}

/* A row's place in the table: the row and the other names it answers to
 * (a NULL-terminated list, or NULL), defined beside the row as
 * lf_codec_entry_<component>. csrc/meson.build generates the table of
 * these (codec_rows.c) from the components list: every component with a
 * codec_table.c (but common, the table's home) is a row, in that order. */
typedef struct lf_codec_entry {
    const fap_codec *codec;
    const char *const *aliases;
} lf_codec_entry;
#define LF_CODEC_ENTRY(comp, row, aliases_) \
    const lf_codec_entry lf_codec_entry_##comp = {&(row), (aliases_)}
/* The generated table: every entry, then NULL. */
extern const lf_codec_entry *const lf_codec_rows[];
#endif
