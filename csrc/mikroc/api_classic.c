/* The vendor's RS485Master_* / RS485Slave_* routines: two global contexts
 * (one master, one slave), as the microcontroller library keeps its state,
 * plus the host mapping (bind/open a port, feed bytes, poll). */
#include <errno.h>
#include <stddef.h>

#include "mikroc_rs485.h"
#include "mikroc/mikroc_internal.h"

static mikrocRS485_ctx g_master, g_slave;
static fap_port *g_owned_port;      /* opened by mikrocRS485_Open */

static mikrocRS485_ctx *ctx_of(int is_master)
{
    return is_master ? &g_master : &g_slave;
}

/* Init resets a context but keeps its port: on the MCU the UART is set up
 * before Init and stays. */
void RS485Master_Init(void)
{
    fap_port *port = g_master.port;
    mikrocRS485_CtxInitMaster(&g_master);
    mikrocRS485_CtxBind(&g_master, port);
}

void RS485Slave_Init(char Slave_address)
{
    fap_port *port = g_slave.port;
    mikrocRS485_CtxInitSlave(&g_slave, (uint8_t)Slave_address);
    mikrocRS485_CtxBind(&g_slave, port);
}

void RS485Master_Receive(char *data_buffer)
{
    mikrocRS485_CtxReceive(&g_master, data_buffer);
}

void RS485Slave_Receive(char *data_buffer)
{
    mikrocRS485_CtxReceive(&g_slave, data_buffer);
}

void RS485Master_Send(char *data_buffer, char datalen, char slave_address)
{
    mikrocRS485_CtxSend(&g_master, data_buffer, (unsigned char)datalen,
                        (uint8_t)slave_address);
}

void RS485Slave_Send(char *data_buffer, char datalen)
{
    mikrocRS485_CtxSend(&g_slave, data_buffer, (unsigned char)datalen, 0);
}

int mikrocRS485_Bind(fap_port *port)
{
    mikrocRS485_CtxBind(&g_master, port);
    mikrocRS485_CtxBind(&g_slave, port);
    return 0;
}

int mikrocRS485_Open(const char *path, unsigned baud, const fap_port_options *opts)
{
    if (!path)
        return -EINVAL;
    if (g_owned_port)
        return -EBUSY;
    fap_port *p = NULL;
    int r = lf_mikroc_port_open(&p, path, baud, opts);
    if (r < 0)
        return r;
    g_owned_port = p;
    return mikrocRS485_Bind(p);
}

void mikrocRS485_Close(void)
{
    if (!g_owned_port)
        return;
    if (g_master.port == g_owned_port)
        mikrocRS485_CtxBind(&g_master, NULL);
    if (g_slave.port == g_owned_port)
        mikrocRS485_CtxBind(&g_slave, NULL);
    fap_port_close(g_owned_port);
    g_owned_port = NULL;
}

void mikrocRS485Master_ReceiveByte(char *data_buffer, unsigned char byte)
{
    mikrocRS485_CtxReceiveByte(&g_master, data_buffer, byte);
}

void mikrocRS485Slave_ReceiveByte(char *data_buffer, unsigned char byte)
{
    mikrocRS485_CtxReceiveByte(&g_slave, data_buffer, byte);
}

int mikrocRS485_Poll(char *data_buffer, int is_master, int timeout_ms)
{
    return mikrocRS485_CtxPoll(ctx_of(is_master), data_buffer, timeout_ms);
}

int mikrocRS485_LastSendError(int is_master)
{
    return ctx_of(is_master)->stats.last_send_error;
}

int mikrocRS485_LastRxError(int is_master)
{
    return ctx_of(is_master)->stats.last_rx_error;
}

void mikrocRS485_GetStats(int is_master, mikrocRS485_stats *out)
{
    mikrocRS485_CtxGetStats(ctx_of(is_master), out);
}
