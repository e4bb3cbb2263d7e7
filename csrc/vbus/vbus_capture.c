/* vbus_capture.c - writes the capture file described in vbus_capture.h. */
#include "vbus/vbus_capture.h"

#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <stdarg.h>
#include <string.h>
#include <unistd.h>

static unsigned long long rel_us(const lf_capture *c, lf_ns t)
{
    return t > c->t0 ? (unsigned long long)((t - c->t0) / LF_NS_PER_US) : 0ull;
}

/* A stdio call just failed: keep its errno if it is the first error. */
static void keep_first_error(lf_capture *c)
{
    if (!c->error)
        c->error = errno ? errno : EIO;
}

/* Something went into the stdio buffer: flush it within LF_CAPTURE_FLUSH_NS. */
static void note_write(lf_capture *c, int failed)
{
    if (failed)
        keep_first_error(c);
    if (c->dirty_since == LF_NEVER)
        c->dirty_since = lf_now_ns();
}

int lf_capture_open(lf_capture *c, const char *path, lf_ns t0, unsigned n_ports,
                    unsigned baud, int echo, uint64_t seed)
{
    memset(c, 0, sizeof *c);
    c->dirty_since = LF_NEVER;
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC | O_NOCTTY, 0644);
    if (fd < 0)
        return -errno;
    c->f = fdopen(fd, "w");
    if (!c->f) {
        int e = errno;
        close(fd);
        return -e;
    }
    c->t0 = t0;
    c->char_ns = lf_char_time_ns(baud);
    int r = fprintf(c->f, "# fap-vbus-capture 1 ports=%u baud=%u echo=%d seed=%" PRIu64 "\n",
                    n_ports, baud, echo ? 1 : 0, seed);
    note_write(c, r < 0);
    return 0;
}

static void line_emit(lf_capture *c)
{
    static const char hex[] = "0123456789abcdef";
    if (!c->line_n)
        return;
    char text[64 + 3 * LF_CAPTURE_BYTES_PER_LINE];
    int len = snprintf(text, 64, "%llu %u", rel_us(c, c->line_t), c->line_port);
    for (size_t i = 0; i < c->line_n; i++) {
        text[len++] = ' ';
        text[len++] = hex[c->line[i] >> 4];
        text[len++] = hex[c->line[i] & 15];
    }
    text[len++] = '\n';
    note_write(c, fwrite(text, 1, (size_t)len, c->f) != (size_t)len);
    c->line_n = 0;
}

void lf_capture_data(lf_capture *c, lf_ns t, unsigned port, const uint8_t *data, size_t n)
{
    if (!c->f)
        return;
    /* unpaced (char_ns 0) every chunk starts its own line */
    if (c->line_n && (port != c->line_port || t != c->line_next || !c->char_ns))
        line_emit(c);
    for (size_t i = 0; i < n; i++) {
        if (c->line_n == LF_CAPTURE_BYTES_PER_LINE)
            line_emit(c);
        if (!c->line_n) {
            c->line_port = port;
            c->line_t = t + (lf_ns)i * c->char_ns;
        }
        c->line[c->line_n++] = data[i];
    }
    c->line_next = t + (lf_ns)n * c->char_ns;
}

void lf_capture_event(lf_capture *c, lf_ns t, const char *kind, const char *fmt, ...)
{
    if (!c->f)
        return;
    line_emit(c);   /* keep the file in the order things happened */
    int r = fprintf(c->f, "# %s t=%llu ", kind, rel_us(c, t));
    va_list ap;
    va_start(ap, fmt);
    int r2 = vfprintf(c->f, fmt, ap);
    va_end(ap);
    int r3 = fputc('\n', c->f);
    note_write(c, r < 0 || r2 < 0 || r3 == EOF);
}

lf_ns lf_capture_due(const lf_capture *c)
{
    if (!c->f)
        return LF_NEVER;
    lf_ns due = LF_NEVER;
    if (c->line_n)
        due = c->line_next + c->char_ns;   /* its sender's wire went quiet */
    if (c->dirty_since != LF_NEVER && c->dirty_since + LF_CAPTURE_FLUSH_NS < due)
        due = c->dirty_since + LF_CAPTURE_FLUSH_NS;
    return due;
}

void lf_capture_tick(lf_capture *c, lf_ns now)
{
    if (!c->f)
        return;
    if (c->line_n && now >= c->line_next + c->char_ns)
        line_emit(c);
    if (c->dirty_since != LF_NEVER && now >= c->dirty_since + LF_CAPTURE_FLUSH_NS) {
        if (fflush(c->f) != 0)
            keep_first_error(c);
        c->dirty_since = LF_NEVER;
    }
}

int lf_capture_close(lf_capture *c)
{
    if (!c->f)
        return 0;
    line_emit(c);
    if (fclose(c->f) != 0)
        keep_first_error(c);
    c->f = NULL;
    return c->error ? -c->error : 0;
}
