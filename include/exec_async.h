/* exec_async.h - the vendor's "asynchronous communications protocol
 * functions": DLE framing and big-endian structure packing.
 *
 * Frame (docs/execasync.md, docs/protocols.md):
 *   DLE STX  Node SeqNo  Data0 .. DataN  DLE ETX  CRC-hi CRC-lo
 * DLE 0x10, STX 0x02, ETX 0x03. A data byte 0x10 is sent twice (0x10 0x10);
 * Node, SeqNo and the CRC bytes are sent raw. The CRC is CRC-16/ARC over the
 * bytes as sent between DLE STX and DLE ETX.
 *
 * These functions are pure: no I/O, no allocation, no global state, safe to
 * call from an interrupt routine. The master/slave engine on top of them is
 * in <exec_async_engine.h>.
 */
#ifndef EXEC_ASYNC_H
#define EXEC_ASYNC_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/* The vendor's types. Define EXEC_ASYNC_HAVE_TYPES before including this
 * header if the application already has byte/word/boolean of these widths. */
#ifndef EXEC_ASYNC_HAVE_TYPES
#define EXEC_ASYNC_HAVE_TYPES
typedef unsigned char  byte;      /* 8 bits  */
typedef unsigned short word;      /* 16 bits */
typedef unsigned char  boolean;   /* 0 false, anything else true */
#endif
#ifndef TRUE
#define TRUE  1
#endif
#ifndef FALSE
#define FALSE 0
#endif

/* VCONST qualifies descriptor tables that may live in read-only memory
 * (a ROM/flash qualifier on small targets); on Linux it is plain const. */
#ifndef VCONST
#define VCONST const
#endif

#define EXEC_ASYNC_DLE 0x10
#define EXEC_ASYNC_STX 0x02
#define EXEC_ASYNC_ETX 0x03

#define EXEC_ASYNC_BROADCAST  255   /* node number of a broadcast (no reply) */
#define EXEC_ASYNC_NODE_MIN   1     /* node numbers a slave takes and a master polls: */
#define EXEC_ASYNC_NODE_MAX   254   /* 0 is no node, 255 the broadcast */
#define EXEC_ASYNC_MAX_DATA   255   /* RawSize is a byte: largest payload */
/* Largest formatted frame for RawSize bytes (every data byte a DLE). */
#define EXEC_ASYNC_FRAME_SIZE(RawSize) (2u * (unsigned)(RawSize) + 8u)
#define EXEC_ASYNC_MAX_FRAME  EXEC_ASYNC_FRAME_SIZE(EXEC_ASYNC_MAX_DATA) /* 518 */

/* execAsyncStateDef.Status after execAsyncByteIn returned true. */
#define EXEC_ASYNC_NONE      0  /* no message reported (receiving / idle)          */
#define EXEC_ASYNC_GOOD      1  /* complete message, CRC correct                   */
#define EXEC_ASYNC_BAD_CRC   2  /* complete message, CRC wrong: do not trust it     */
#define EXEC_ASYNC_OVERFLOW  3  /* payload longer than the buffer: Buffer holds the
                                   first BufferSize bytes; the rest of that frame is
                                   skipped (the decoder stays in step with the DLEs) */
#define EXEC_ASYNC_FRAMING   4  /* DLE followed by a byte other than DLE/STX/ETX, or
                                   a new DLE STX before the DLE ETX (the new frame
                                   is then already being received)                 */

/* Receive state of one byte stream (section "2.5.6", missing in the seed).
 *
 * - A zero-filled structure is a valid initial state (a static variable in
 *   an interrupt routine needs no initialisation); zero-filling it again
 *   resets the decoder (resynchronise on the next DLE STX).
 * - Node, SeqNo, Length and Status are valid after a true return, until the
 *   next call. Buffer then holds Length payload bytes, unstuffed, without
 *   Node/SeqNo/CRC. The next call starts on the next frame with the same
 *   state (and the same Buffer): consume Buffer before feeding more bytes.
 * - Buffer must hold BufferSize bytes; BufferSize 0 (the zero-filled value)
 *   means EXEC_ASYNC_MAX_DATA (255), which holds any payload a sender can
 *   produce with execAsyncBufferOut. A smaller BufferSize is allowed and
 *   survives every reset the decoder does itself.
 * - Bytes outside a frame (noise before DLE STX) are skipped silently.
 */
struct execAsyncStateDef {
    /* results */
    byte Status;      /* EXEC_ASYNC_GOOD / BAD_CRC / OVERFLOW / FRAMING */
    byte Node;        /* node number of the frame (raw byte after DLE STX) */
    byte SeqNo;       /* its sequence number */
    word Length;      /* payload bytes in Buffer */
    /* configuration */
    byte BufferSize;  /* capacity of Buffer, 0 = EXEC_ASYNC_MAX_DATA */
    /* progress (private) */
    byte Phase;
    byte CrcHigh;     /* received CRC, high byte */
    word Crc;         /* running CRC of the bytes as sent */
};

/* Format a frame into TxBuf, which must hold 2*RawSize+8 bytes.
 * Raw may be NULL when RawSize is 0. Returns the number of bytes written. */
word execAsyncBufferOut(byte Node, byte *Raw, byte *TxBuf, byte RawSize, byte SeqNo);

/* Feed one received byte. Returns true when a message is complete (GOOD)
 * or has been found corrupted (BAD_CRC, OVERFLOW, FRAMING): see State. */
boolean execAsyncByteIn(byte Value, struct execAsyncStateDef *State, byte *Buffer);

/* Structure packing (the other half of the missing section 2.5.6).
 *
 * A descriptor is an array of struct execStructDef, one entry per member
 * (or per array member), ended by an entry whose Size is 0:
 *   Offset  offset of the member in the native structure (offsetof)
 *   Size    size of ONE item in bytes; sizes 2, 4 and 8 are integers (or
 *           IEEE floats) and are byte-reordered to big-endian on the wire,
 *           any other size (1, or e.g. 3 or 16 for an opaque blob) is copied
 *           as is
 *   Count   number of consecutive items (an array); 0 counts as 1
 * The terminator's Offset is sizeof the native structure (0 = unknown: the
 * end of the last member is used); it is what the UnPack functions return.
 *
 * On the wire the members follow each other in descriptor order with no
 * padding. Example:
 *
 *   struct reading { byte id; word raw; long total; short delta[3]; };
 *   (long is 8 bytes on 64-bit Linux, so the packed size below is 17)
 *   static struct execStructDef VCONST readingDesc[] = {
 *       EXEC_STRUCT_ITEM(struct reading, id),
 *       EXEC_STRUCT_ITEM(struct reading, raw),
 *       EXEC_STRUCT_ITEM(struct reading, total),
 *       EXEC_STRUCT_ARRAY(struct reading, delta),
 *       EXEC_STRUCT_END(struct reading)
 *   };
 *   byte wire[sizeof(struct reading)];
 *   word n = execPackDataEx(wire, (byte *)&r, readingDesc);   -> 1+2+8+6
 *
 * Ex versions: Target and Source must not overlap; any descriptor order.
 * In-place versions: the entries must be in ascending, non-overlapping
 * Offset order; otherwise nothing is changed and 0 is returned. Padding
 * bytes of an unpacked structure are left as they were (Ex) or hold
 * leftover bytes (in place).
 */
struct execStructDef {
    word Offset;
    word Size;
    word Count;
};

#define EXEC_STRUCT_ITEM(type, member) \
    { (word)offsetof(type, member), (word)sizeof(((type *)0)->member), 1 }
#define EXEC_STRUCT_ARRAY(type, member) \
    { (word)offsetof(type, member), (word)sizeof(((type *)0)->member[0]), \
      (word)(sizeof(((type *)0)->member) / sizeof(((type *)0)->member[0])) }
#define EXEC_STRUCT_END(type) { (word)sizeof(type), 0, 0 }

/* Native -> packed big-endian. Return the packed size. */
word execPackDataEx(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor);
word execPackData(byte *Buffer, struct execStructDef VCONST *Descriptor);
/* Packed big-endian -> native. Return the native size (see terminator). */
word execUnPackDataEx(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor);
word execUnPackData(byte *Buffer, struct execStructDef VCONST *Descriptor);
/* The vendor prototypes above return a 16-bit word: when the size to
 * return (packed size for Pack, native size for UnPack) exceeds 65535 they
 * return 0 and write nothing, never a wrapped size. These variants do the
 * same work for any size and return it as a size_t (libfap extension). */
size_t execPackDataExWide(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor);
size_t execPackDataWide(byte *Buffer, struct execStructDef VCONST *Descriptor);
size_t execUnPackDataExWide(byte *Target, byte *Source, struct execStructDef VCONST *Descriptor);
size_t execUnPackDataWide(byte *Buffer, struct execStructDef VCONST *Descriptor);

#ifdef __cplusplus
}
#endif
#endif /* EXEC_ASYNC_H */
