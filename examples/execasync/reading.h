/* The structures both example programs exchange, and their descriptors:
 * native C structs on each side, packed big-endian on the wire. */
#ifndef EXAMPLE_READING_H
#define EXAMPLE_READING_H
#include <stdint.h>

#include <exec_async.h>

struct command {            /* master -> slave */
    byte code;              /* 1 = read */
    word channel;
};

struct reading {            /* slave -> master */
    byte channel;
    word raw;
    int32_t total;
    int16_t delta[3];
};

static struct execStructDef VCONST command_desc[] = {
    EXEC_STRUCT_ITEM(struct command, code),
    EXEC_STRUCT_ITEM(struct command, channel),
    EXEC_STRUCT_END(struct command),
};

static struct execStructDef VCONST reading_desc[] = {
    EXEC_STRUCT_ITEM(struct reading, channel),
    EXEC_STRUCT_ITEM(struct reading, raw),
    EXEC_STRUCT_ITEM(struct reading, total),
    EXEC_STRUCT_ARRAY(struct reading, delta),
    EXEC_STRUCT_END(struct reading),   /* packed: 1 + 2 + 4 + 6 = 13 bytes */
};
#endif
