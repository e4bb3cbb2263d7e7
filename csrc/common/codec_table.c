/* The codec table (include/fap_codec.h): one row per protocol, each row
 * defined beside its scanner (the codec_table.c file of each csrc/ protocol folder). */
#include <string.h>

#include "fap_codec.h"

extern const fap_codec lf_codec_fap, lf_codec_exec, lf_codec_mikroc;

static const fap_codec *const table[] = {&lf_codec_fap, &lf_codec_exec, &lf_codec_mikroc};

const fap_codec *fap_codec_at(size_t i)
{
    return i < sizeof table / sizeof table[0] ? table[i] : NULL;
}

const fap_codec *fap_codec_find(const char *name)
{
    if (!name)
        return NULL;
    if (strcmp(name, "execasync") == 0)     /* the old spelling, accepted on input */
        name = "exec";
    for (size_t i = 0; i < sizeof table / sizeof table[0]; i++)
        if (strcmp(table[i]->name, name) == 0)
            return table[i];
    return NULL;
}
