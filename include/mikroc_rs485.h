/* mikroc_rs485.h - the mikroC RS-485 library (master/slave, 0..3 data bytes
 * per frame) for Linux hosts.
 *
 * Three layers, all declared here:
 *
 *  1. The codec (sans-I/O): mikrocRS485_Encode() builds a frame,
 *     mikrocRS485_decoder turns received bytes into frames or errors.
 *  2. The re-entrant node context (mikrocRS485_ctx): a master or slave that
 *     fills the vendor's receive buffer one byte at a time, applies the
 *     address rules, and sends/reads through a bound fap_port.
 *  3. The vendor routines with their documented prototypes
 *     (RS485Master_Init ... RS485Slave_Send), which work on two global
 *     contexts (one master, one slave) like the microcontroller library,
 *     plus the host mapping of the MCU's UART and RS485_rxtx_pin.
 *
 * Frame on the wire (docs/mikroc.md has the full rules):
 *   0x96 | ADDRESS | DATALEN | DATA1..3 (0..3 bytes) | CRC | 0xA9
 *
 * Host mapping of the MCU peripherals
 * -----------------------------------
 * On the microcontroller the routines use the UART set up by UARTx_Init()
 * and drive the transceiver through `sbit RS485_rxtx_pin`. On a host:
 *  - the UART is a fap_port (fap_port_open: device path, baud rate);
 *  - RS485_rxtx_pin is the port's RS-485 direction mode (fap_rs485_mode):
 *    FAP_RS485_KERNEL (the driver toggles RTS), FAP_RS485_SOFT_RTS (RTS is
 *    the rxtx pin: asserted, bytes written, tcdrain(), released) or
 *    FAP_RS485_NONE (auto-direction transceiver, USB adapter, pty);
 *  - mikrocRS485_Bind(port) connects the vendor routines to that port.
 *    Send then writes the whole frame through fap_port_write() (which
 *    switches direction per the mode and returns when the last bit left),
 *    and Receive takes the next received byte: a non-blocking read, no
 *    byte = nothing happens, exactly like calling it with no byte in the
 *    UART register.
 *  - On the MCU Receive runs in the UART interrupt; on a host, call
 *    mikrocRS485_Poll() (reads with a deadline until a flag goes up) or feed
 *    bytes you read yourself with mikrocRS485Master_ReceiveByte() /
 *    mikrocRS485Slave_ReceiveByte().
 *
 * Threads: a context (and each of the two global contexts) is used by one
 * receiving thread at a time; Send may run in another thread at the same
 * time (it touches only the port). Init and Bind before anything else.
 */
#ifndef MIKROC_RS485_H
#define MIKROC_RS485_H

#include <stdint.h>
#include <fap_port.h>
#include <fap_trace.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- wire constants ---------------------------------------------------- */
#define MIKROC_RS485_START_BYTE    0x96
#define MIKROC_RS485_STOP_BYTE     0xA9
#define MIKROC_RS485_BROADCAST     50    /* reaches every slave but 150 and 169 */
#define MIKROC_RS485_ADDR_MIN      0     /* any address byte is a node: the API */
#define MIKROC_RS485_ADDR_MAX      255   /* takes a uint8_t and checks no range */
#define MIKROC_RS485_MAX_DATA      3
#define MIKROC_RS485_FRAME_MIN     5     /* no data */
#define MIKROC_RS485_FRAME_MAX     8     /* three data bytes */

/* DATALEN bits */
#define MIKROC_RS485_DL_MASTER     0x80  /* 1 = master sends, 0 = slave sends */
#define MIKROC_RS485_DL_ADDR_ESC   0x40  /* address was XORed with 1 */
#define MIKROC_RS485_DL_FIXED      0x20  /* always 0; a receiver rejects it set */
#define MIKROC_RS485_DL_DATA_ESC(i) (0x04u << (i)) /* DATA(i+1) was XORed with 1, i = 0..2 */
#define MIKROC_RS485_DL_COUNT      0x03  /* number of data bytes */

/* ---- the vendor receive buffers ----------------------------------------- */
#define MIKROC_RS485_MASTER_BUFFER 7     /* data0..2, count, ready, error, slave address */
#define MIKROC_RS485_SLAVE_BUFFER  6     /* data0..2, count, ready, error */
#define MIKROC_RS485_IDX_COUNT     3
#define MIKROC_RS485_IDX_READY     4
#define MIKROC_RS485_IDX_ERROR     5
#define MIKROC_RS485_IDX_ADDRESS   6     /* master buffer only */
#define MIKROC_RS485_FLAG_SET      255

/* ---- result codes --------------------------------------------------------
 * Decoder results and frame errors. The frame errors are negative and lie
 * outside the errno range (like FAP_PORT_E*), so one int can hold either a
 * frame error or a -errno from the port layer. */
#define MIKROC_RS485_MORE          0      /* decoder: need more bytes */
#define MIKROC_RS485_FRAME         1      /* decoder: a valid frame is in *out */
#define MIKROC_RS485_ECRC      (-10101)   /* checksum does not match */
#define MIKROC_RS485_EFORMAT   (-10102)   /* DATALEN bit 5 set, escape flag on a
                                             missing byte or on a byte that was
                                             not escaped */
#define MIKROC_RS485_ESHORT    (-10103)   /* stop byte before the frame was complete */
#define MIKROC_RS485_ELONG     (-10104)   /* no stop byte where DATALEN says it is */
#define MIKROC_RS485_EABORT    (-10105)   /* a new start byte cut the frame off */
#define MIKROC_RS485_EOVERRUN  (-10106)   /* a frame arrived while the ready flag
                                             was still set: it was not stored */

/* Name of a MIKROC_RS485_E* code, or of a port-layer/errno code. */
const char *mikrocRS485_strerror(int code);

/* ---- 1. codec (sans-I/O) ------------------------------------------------ */

/* Build the frame for datalen (0..3) bytes to/from `address` into out
 * (at least MIKROC_RS485_FRAME_MAX bytes). from_master selects DATALEN
 * bit 7. Returns the frame length (5..8), or -EINVAL when datalen > 3 or
 * data is NULL with datalen > 0 (nothing written). */
int mikrocRS485_Encode(uint8_t *out, const uint8_t *data, unsigned datalen,
                       uint8_t address, int from_master);

/* What the decoder knows about a frame. On MIKROC_RS485_FRAME everything is
 * valid. On an error, `header` says how much of it arrived: 0 nothing,
 * 1 the address (raw; the escape flag was not seen yet), 2 the address
 * (unescaped if DATALEN says so) and DATALEN; data/count are then unset. */
typedef struct mikrocRS485_frame {
    uint8_t address;    /* unescaped */
    uint8_t datalen;    /* DATALEN byte as received, with its flags */
    uint8_t count;      /* data bytes, 0..3 */
    uint8_t data[MIKROC_RS485_MAX_DATA]; /* unescaped */
    uint8_t header;     /* 0, 1 or 2: see above */
} mikrocRS485_frame;

/* Byte-wise decoder. Zero-filled = freshly initialised. Fields private. */
typedef struct mikrocRS485_decoder {
    uint8_t in_frame;   /* a start byte was seen */
    uint8_t n;          /* bytes after the start byte held in raw */
    uint8_t raw[6];     /* address, DATALEN, data..., CRC as received */
} mikrocRS485_decoder;

void mikrocRS485_DecoderInit(mikrocRS485_decoder *d);
/* Feed one received byte. Returns MIKROC_RS485_MORE, MIKROC_RS485_FRAME
 * (*out filled) or a MIKROC_RS485_E* frame error (*out describes what
 * arrived). Bytes outside a frame are skipped; a 0x96 always starts a new
 * frame (the one in progress is reported as MIKROC_RS485_EABORT). After an
 * error the decoder skips bytes until the next 0x96. */
int mikrocRS485_DecoderFeed(mikrocRS485_decoder *d, uint8_t byte,
                            mikrocRS485_frame *out);

/* ---- 2. node context (re-entrant) --------------------------------------- */

typedef enum mikrocRS485_role {
    MIKROC_RS485_ROLE_NONE = 0,
    MIKROC_RS485_ROLE_MASTER = 1,
    MIKROC_RS485_ROLE_SLAVE = 2
} mikrocRS485_role;

typedef struct mikrocRS485_stats {
    uint32_t frames;          /* frames delivered (ready flag set) */
    uint32_t errors;          /* error flag set (damaged frame for us, overrun) */
    uint32_t overruns;        /* frames not stored: ready flag still set */
    uint32_t ignored;         /* valid frames for another address or direction */
    uint32_t damaged;         /* damaged frames heard, for any address */
    int last_rx_error;        /* last MIKROC_RS485_E* (for us) or read -errno, 0 none */
    int last_send_error;      /* result of the last Send: 0 or a negative code */
    uint8_t last_address;     /* address of the last delivered frame */
} mikrocRS485_stats;

#define MIKROC_RS485_RXBUF 64

/* One master or slave. Fields are private; the struct is public so it can
 * live in static storage or on the stack, like the MCU library's state. */
typedef struct mikrocRS485_ctx {
    mikrocRS485_role role;
    uint8_t address;                 /* slave: its own address */
    mikrocRS485_decoder dec;
    fap_port *port;                  /* bound port or NULL */
    int owns_port;                   /* opened by mikrocRS485_CtxOpen */
    uint8_t rx[MIKROC_RS485_RXBUF];  /* bytes read from the port, not fed yet */
    uint16_t rx_pos, rx_len;
    mikrocRS485_stats stats;
    fap_trace_fn trace;              /* wire trace hook, see mikrocRS485_CtxSetTrace */
    void *trace_ctx;
} mikrocRS485_ctx;

/* Initialise as master / as slave at `address` (0..255; see docs on 50,
 * 150 and 169). Clears everything, including the port binding (so call
 * mikrocRS485_CtxClose first on a context that opened its port). */
void mikrocRS485_CtxInitMaster(mikrocRS485_ctx *c);
void mikrocRS485_CtxInitSlave(mikrocRS485_ctx *c, uint8_t address);

/* Feed one received byte (sans-I/O). data_buffer is the vendor buffer:
 * 7 bytes for a master, 6 for a slave. On a valid frame for this node:
 * data[0..2] (unused ones 0), count, ready = 255 and (master) the slave's
 * address; on a damaged frame for this node: error = 255. The flags are
 * never cleared here: the application clears them. A frame arriving while
 * ready is still 255 is not stored (error = 255, MIKROC_RS485_EOVERRUN). */
void mikrocRS485_CtxReceiveByte(mikrocRS485_ctx *c, char *data_buffer, uint8_t byte);

/* Bind to an open port (NULL unbinds). Drops bytes read but not fed yet.
 * Returns 0. The port stays the caller's; a port the context opened itself
 * (mikrocRS485_CtxOpen) is closed when another one (or NULL) is bound. */
int mikrocRS485_CtxBind(mikrocRS485_ctx *c, fap_port *port);

/* Open `path` (opts NULL = fap_port defaults; baud 0 keeps the options'
 * rate) and bind it; the context owns the port until mikrocRS485_CtxClose.
 * Call after Init. Returns 0, -EBUSY if the context already owns a port,
 * or the negative error of fap_port_open. */
int mikrocRS485_CtxOpen(mikrocRS485_ctx *c, const char *path, unsigned baud,
                        const fap_port_options *opts);
/* Unbind, and close the port if the context opened it. */
void mikrocRS485_CtxClose(mikrocRS485_ctx *c);

/* Take the next received byte from the bound port, without waiting, and
 * feed it. No port or no byte: nothing happens (a read error is recorded in
 * stats.last_rx_error). */
void mikrocRS485_CtxReceive(mikrocRS485_ctx *c, char *data_buffer);

/* Flags returned by the Poll routines (bit mask). */
#define MIKROC_RS485_POLL_READY 1
#define MIKROC_RS485_POLL_ERROR 2

/* Read from the bound port and feed bytes until the ready or error flag of
 * data_buffer is 255 (already set on entry: returns at once), or until
 * timeout_ms passes (0 = only what is already there, < 0 = no limit).
 * Reads no byte past the end of the frame that raised the flag.
 * Returns the MIKROC_RS485_POLL_* mask of the flags set, 0 on timeout,
 * -ENOTCONN with no port bound, -EPERM before Init, or a negative port
 * error (-EIO, -ENXIO ... when the device vanished). */
int mikrocRS485_CtxPoll(mikrocRS485_ctx *c, char *data_buffer, int timeout_ms);

/* Encode and write a frame: a master to `address`, a slave from its own
 * address (the argument is ignored). datalen > 3 is REJECTED: nothing is
 * sent and -EINVAL returned. Returns 0, -EINVAL, -EPERM before Init,
 * -ENOTCONN with no port, or the port's negative error. */
int mikrocRS485_CtxSend(mikrocRS485_ctx *c, const char *data_buffer,
                        unsigned datalen, uint8_t address);

/* Forget a half-received frame, bytes read but not fed, and input still
 * waiting in the bound port (read away without waiting, up to 4 KiB;
 * output is not touched). A master calls it before a
 * request so a late answer to an earlier one cannot pass for the reply.
 * The flags in the application's buffer are not touched. Returns 0 or the
 * port's negative error. */
int mikrocRS485_CtxResetRx(mikrocRS485_ctx *c);

void mikrocRS485_CtxGetStats(const mikrocRS485_ctx *c, mikrocRS485_stats *out);
/* Install (or with NULL remove) the wire trace hook (fap_trace.h): every
 * frame sent and every frame received (any address; damaged ones with
 * their status), called on the thread inside CtxSend / CtxReceiveByte
 * (CtxReceive, CtxPoll). Call after CtxInit* (which clears it) and while
 * no other thread is inside a call on this context: a context has no lock
 * of its own. */
void mikrocRS485_CtxSetTrace(mikrocRS485_ctx *c, fap_trace_fn fn, void *ctx);

/* ---- 3. vendor routines (documented prototypes) -------------------------
 * They use two global contexts, one master and one slave. */
void RS485Master_Init(void);
void RS485Master_Receive(char *data_buffer);
void RS485Master_Send(char *data_buffer, char datalen, char slave_address);
void RS485Slave_Init(char Slave_address);
void RS485Slave_Receive(char *data_buffer);
void RS485Slave_Send(char *data_buffer, char datalen);

/* Host mapping: bind both global contexts to an open port (NULL unbinds).
 * Init keeps the binding, so Bind may come before or after Init. Returns 0. */
int mikrocRS485_Bind(fap_port *port);

/* Open `path` (opts NULL = fap_port defaults at `baud`; baud 0 keeps the
 * options' rate) and bind it: the host's UARTx_Init. The port is owned by
 * the library until mikrocRS485_Close(). Returns 0 or the negative error of
 * fap_port_open (-EBUSY when already open: close first). */
int mikrocRS485_Open(const char *path, unsigned baud, const fap_port_options *opts);
void mikrocRS485_Close(void);

/* Feed one byte you read yourself to the global master / slave. */
void mikrocRS485Master_ReceiveByte(char *data_buffer, unsigned char byte);
void mikrocRS485Slave_ReceiveByte(char *data_buffer, unsigned char byte);

/* mikrocRS485_CtxPoll on the global master (is_master != 0) or slave. */
int mikrocRS485_Poll(char *data_buffer, int is_master, int timeout_ms);

/* The vendor Send routines return nothing: their result (0, -EINVAL for
 * datalen > 3, -EPERM before Init, -ENOTCONN, a port error) is kept here. */
int mikrocRS485_LastSendError(int is_master);
/* Last frame error for this node or read error seen by Receive/Poll. */
int mikrocRS485_LastRxError(int is_master);
void mikrocRS485_GetStats(int is_master, mikrocRS485_stats *out);

#ifdef __cplusplus
}
#endif
#endif /* MIKROC_RS485_H */
