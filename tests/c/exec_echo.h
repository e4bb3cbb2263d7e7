/* The exec async slave handler most tests need: the reply is the request. */
#ifndef LF_TEST_EXEC_ECHO_H
#define LF_TEST_EXEC_ECHO_H

#include <string.h>

#include "exec_async_engine.h"

static inline int test_exec_echo(void *ctx, const execSlaveRequest *req, byte *reply, word cap)
{
    (void)ctx;
    if (req->len > cap)
        return -1;
    memcpy(reply, req->data, req->len);
    return req->len;
}

#endif
