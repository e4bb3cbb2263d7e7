/* The stream bytes a span-reporting scanner has not reported yet, for the
 * codec table (include/fap_codec.h). The exec and mikroC scanners report a
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
#endif
