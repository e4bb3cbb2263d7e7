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
static word native_size(struct execStructDef VCONST *d)
{
    unsigned end = 0;
    for (; d->Size; d++) {
        unsigned e = (unsigned)d->Offset + (unsigned)d->Size * item_count(d);
        if (e > end)
            end = e;
    }
    return d->Offset ? d->Offset : (word)end;
}

/* In place needs ascending, non-overlapping items (packed data is never
 * ahead of the native data it comes from). */
static int ascending(struct execStructDef VCONST *d)
{
    unsigned end = 0;
    for (; d->Size; d++) {
        if (d->Offset < end)
            return 0;
        end = (unsigned)d->Offset + (unsigned)d->Size * item_count(d);
    }
    return 1;
}

word execPackDataEx(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor)
{
    unsigned pos = 0;
    for (struct execStructDef VCONST *d = Descriptor; d->Size; d++) {
        for (unsigned i = 0; i < item_count(d); i++) {
            convert_item(Target + pos, Source + d->Offset + (size_t)i * d->Size, d->Size);
            pos += d->Size;
        }
    }
    return (word)pos;
}

word execPackData(byte *Buffer, struct execStructDef VCONST *Descriptor)
{
    if (!ascending(Descriptor))
        return 0;
    /* forward: every item moves down (or stays), never over unread data */
    return execPackDataEx(Buffer, Buffer, Descriptor);
}

word execUnPackDataEx(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor)
{
    unsigned pos = 0;
    for (struct execStructDef VCONST *d = Descriptor; d->Size; d++) {
        for (unsigned i = 0; i < item_count(d); i++) {
            convert_item(Target + d->Offset + (size_t)i * d->Size, Source + pos, d->Size);
            pos += d->Size;
        }
    }
    return native_size(Descriptor);
}

word execUnPackData(byte *Buffer, struct execStructDef VCONST *Descriptor)
{
    if (!ascending(Descriptor))
        return 0;
    /* backward: every item moves up (or stays), so start with the last one */
    unsigned n = 0, pos = 0;
    for (struct execStructDef VCONST *d = Descriptor; d->Size; d++) {
        n++;
        pos += (unsigned)d->Size * item_count(d);
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
