/* execPackData[Ex] / execUnPackData[Ex] (and the Wide variants) with
 * arbitrary descriptors. Buffers are sized from the descriptor exactly
 * (heap, so ASan sees any access beyond). Properties: the packed size is
 * the sum of the items; unpacking what was packed restores every item's
 * bytes; the in-place functions agree with the Ex ones when they accept a
 * descriptor (ascending, non-overlapping) and refuse it otherwise without
 * touching the buffer; a size that fits no word is reported as 0. */
#include "fuzz_util.h"
#include "exec_async.h"

#define MAX_ITEMS 12

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fz f = {data, size};
    struct execStructDef d[MAX_ITEMS + 1];
    unsigned n = fz_u8(&f) % (MAX_ITEMS + 1);
    size_t end = 0, packed = 0;
    for (unsigned i = 0; i < n; i++) {
        d[i].Offset = fz_u16(&f) % 2048;
        static const word sizes[] = {1, 2, 4, 8, 3, 16};
        uint8_t s = fz_u8(&f);
        d[i].Size = (s & 0x80) ? (word)(1 + s % 40) : sizes[s % 6];
        d[i].Count = fz_u8(&f) % 20;           /* 0 = 1 */
        size_t c = d[i].Count ? d[i].Count : 1;
        size_t e = (size_t)d[i].Offset + (size_t)d[i].Size * c;
        if (e > end)
            end = e;
        packed += (size_t)d[i].Size * c;
    }
    d[n].Offset = fz_u8(&f) & 1 ? (word)end : 0;
    d[n].Size = 0;
    d[n].Count = 0;
    size_t native = end ? end : 1;
    byte *src = malloc(native), *wire = malloc(packed ? packed : 1), *back = malloc(native);
    for (size_t i = 0; i < native; i++)
        src[i] = (byte)(fz_u8(&f) ^ i);
    PROPERTY(execPackDataExWide(wire, src, d) == packed);
    PROPERTY(execPackDataEx(wire, src, d) == packed);        /* all fit a word here */
    memset(back, 0, native);
    size_t ns = execUnPackDataExWide(back, wire, d);
    PROPERTY(ns == (d[n].Offset ? d[n].Offset : end));
    /* every item whose bytes no later item overwrote comes back: check
     * by unpacking the last writer of each byte */
    static byte owner_ok[2048 + 40 * 20 + 8];
    memset(owner_ok, 0, native);
    for (unsigned i = 0; i < n; i++) {
        size_t c = d[i].Count ? d[i].Count : 1;
        for (size_t k = d[i].Offset; k < d[i].Offset + (size_t)d[i].Size * c; k++)
            owner_ok[k] = (byte)(i + 1);
    }
    byte *again = malloc(packed ? packed : 1);
    execPackDataExWide(again, back, d);
    /* pack(unpack(pack(x))) == pack(x) for bytes owned by one item only */
    int overlap = 0;
    for (unsigned i = 0; i < n && !overlap; i++) {
        size_t c = d[i].Count ? d[i].Count : 1;
        for (size_t k = d[i].Offset; k < d[i].Offset + (size_t)d[i].Size * c; k++)
            if (owner_ok[k] != i + 1)
                overlap = 1;
    }
    if (!overlap)
        PROPERTY(!memcmp(again, wire, packed));
    /* in place: accepted iff ascending and non-overlapping */
    int asc = 1;
    size_t prev = 0;
    for (unsigned i = 0; i < n; i++) {
        size_t c = d[i].Count ? d[i].Count : 1;
        if (d[i].Offset < prev)
            asc = 0;
        prev = (size_t)d[i].Offset + (size_t)d[i].Size * c;
    }
    byte *inplace = malloc(native);
    memcpy(inplace, src, native);
    size_t r = execPackDataWide(inplace, d);
    if (asc) {
        PROPERTY(r == packed && !memcmp(inplace, wire, packed));
        size_t u = execUnPackDataWide(inplace, d);
        PROPERTY(u == ns);
        for (unsigned i = 0; i < n; i++) {       /* every item back in place */
            size_t c = d[i].Count ? d[i].Count : 1;
            PROPERTY(!memcmp(inplace + d[i].Offset, back + d[i].Offset, (size_t)d[i].Size * c));
        }
    } else {
        PROPERTY(r == 0 && !memcmp(inplace, src, native));
        PROPERTY(execUnPackData(inplace, d) == 0);
    }
    free(src);
    free(wire);
    free(back);
    free(again);
    free(inplace);
    return 0;
}
