/* Exec async structure packing: native layout <-> 1-byte-aligned big-endian.
 * The descriptor format is documented in exec_async.h and docs/execasync.md. */
#include "exec_async.h"

#include <string.h>

static int host_is_little_endian(void)
{
    const unsigned one = 1;
    return *(const unsigned char *)&one == 1;
}

/* Sizes that are numbers and change byte order; others are opaque bytes. */
static int is_number_size(unsigned size)
{
    return size == 2 || size == 4 || size == 8;
}

static unsigned item_count(struct execStructDef VCONST *d)
{
    return d->Count ? d->Count : 1u;
}

/* Copy one item, reversing its bytes when it is a number on a little-endian
 * host. dst and src may overlap (in-place conversions): read fully first. */
static void convert_item(byte *dst, const byte *src, unsigned size)
{
    if (is_number_size(size) && host_is_little_endian()) {
        byte tmp[8];
        memcpy(tmp, src, size);
        for (unsigned i = 0; i < size; i++)
            dst[i] = tmp[size - 1 - i];
    } else {
        memmove(dst, src, size);
    }
}

/* Native size: the terminator's Offset, else the end of the furthest item. */
static size_t native_size(struct execStructDef VCONST *d)
{
    size_t end = 0;
    for (; d->Size; d++) {
        size_t e = (size_t)d->Offset + (size_t)d->Size * item_count(d);
        if (e > end)
            end = e;
    }
    return d->Offset ? d->Offset : end;
}

static size_t packed_size(struct execStructDef VCONST *d)
{
    size_t n = 0;
    for (; d->Size; d++)
        n += (size_t)d->Size * item_count(d);
    return n;
}

/* In place needs ascending, non-overlapping items (packed data is never
 * ahead of the native data it comes from). */
static int ascending(struct execStructDef VCONST *d)
{
    size_t end = 0;
    for (; d->Size; d++) {
        if (d->Offset < end)
            return 0;
        end = (size_t)d->Offset + (size_t)d->Size * item_count(d);
    }
    return 1;
}

/* The vendor prototypes return a word: a size that does not fit is
 * reported as 0 with nothing written (never a wrapped size); the Wide
 * variants return size_t. */
#define FITS_WORD(n) ((n) <= 0xFFFFu)

size_t execPackDataExWide(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor)
{
    size_t pos = 0;
    for (struct execStructDef VCONST *d = Descriptor; d->Size; d++) {
        for (unsigned i = 0; i < item_count(d); i++) {
            convert_item(Target + pos, Source + d->Offset + (size_t)i * d->Size, d->Size);
            pos += d->Size;
        }
    }
    return pos;
}

word execPackDataEx(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor)
{
    if (!FITS_WORD(packed_size(Descriptor)))
        return 0;
    return (word)execPackDataExWide(Target, Source, Descriptor);
}

size_t execPackDataWide(byte *Buffer, struct execStructDef VCONST *Descriptor)
{
    if (!ascending(Descriptor))
        return 0;
    /* forward: every item moves down (or stays), never over unread data */
    return execPackDataExWide(Buffer, Buffer, Descriptor);
}

word execPackData(byte *Buffer, struct execStructDef VCONST *Descriptor)
{
    if (!FITS_WORD(packed_size(Descriptor)))
        return 0;
    return (word)execPackDataWide(Buffer, Descriptor);
}

size_t execUnPackDataExWide(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor)
{
    size_t pos = 0;
    for (struct execStructDef VCONST *d = Descriptor; d->Size; d++) {
        for (unsigned i = 0; i < item_count(d); i++) {
            convert_item(Target + d->Offset + (size_t)i * d->Size, Source + pos, d->Size);
            pos += d->Size;
        }
    }
    return native_size(Descriptor);
}

word execUnPackDataEx(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor)
{
    if (!FITS_WORD(native_size(Descriptor)))
        return 0;
    return (word)execUnPackDataExWide(Target, Source, Descriptor);
}

size_t execUnPackDataWide(byte *Buffer, struct execStructDef VCONST *Descriptor)
{
    if (!ascending(Descriptor))
        return 0;
    /* backward: every item moves up (or stays), so start with the last one */
    size_t n = 0, pos = 0;
    for (struct execStructDef VCONST *d = Descriptor; d->Size; d++) {
        n++;
        pos += (size_t)d->Size * item_count(d);
    }
    while (n--) {
        struct execStructDef VCONST *d = Descriptor + n;
        for (unsigned i = item_count(d); i--;) {
            pos -= d->Size;
            convert_item(Buffer + d->Offset + (size_t)i * d->Size, Buffer + pos, d->Size);
        }
    }
    return native_size(Descriptor);
}

word execUnPackData(byte *Buffer, struct execStructDef VCONST *Descriptor)
{
    if (!FITS_WORD(native_size(Descriptor)))
        return 0;
    return (word)execUnPackDataWide(Buffer, Descriptor);
}
