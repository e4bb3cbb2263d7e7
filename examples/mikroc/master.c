/* mikroC RS-485 master example, on a Linux host.
 *
 * The vendor's master example sends one byte to slave 160, and every reply
 * (the byte + 1) is sent back incremented again. The same program here:
 * UART1_Init() becomes mikrocRS485_Open() and the UART interrupt that calls
 * RS485Master_Receive() becomes mikrocRS485_Poll().
 *
 *   mikroc_master DEVICE [BAUD [ROUNDS]]     e.g. mikroc_master /dev/ttyUSB0 9600 10
 *
 * Try it on a virtual bus:  fap bus --ports 2  (or fap_py.vbus.VirtualBus)
 * and run mikroc_slave on the other port.
 */
#include <stdio.h>
#include <stdlib.h>

#include <mikroc_rs485.h>

char dat[10];                     /* buffer for receiving/sending messages */

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: %s DEVICE [BAUD [ROUNDS]]\n", argv[0]);
        return 2;
    }
    unsigned baud = argc > 2 ? (unsigned)strtoul(argv[2], NULL, 10) : 9600;
    int rounds = argc > 3 ? atoi(argv[3]) : 10;

    int r = mikrocRS485_Open(argv[1], baud, NULL);   /* UART1_Init(9600) */
    if (r < 0) {
        fprintf(stderr, "%s: %s\n", argv[1], mikrocRS485_strerror(r));
        return 1;
    }
    RS485Master_Init();           /* initialize MCU as Master */

    dat[0] = (char)0xAA;
    dat[1] = (char)0xF0;
    dat[2] = (char)0x0F;
    dat[4] = 0;                   /* ensure that message received flag is 0 */
    dat[5] = 0;                   /* ensure that error flag is 0 */
    dat[6] = 0;

    RS485Master_Send(dat, 1, (char)160);
    if (mikrocRS485_LastSendError(1) < 0) {
        fprintf(stderr, "send: %s\n", mikrocRS485_strerror(mikrocRS485_LastSendError(1)));
        mikrocRS485_Close();      /* close what we opened, on every path */
        return 1;
    }

    int status = 0, silent = 0;
    for (int done = 0; done < rounds;) {
        /* the MCU's interrupt routine: here, wait up to 1 s for the flags */
        r = mikrocRS485_Poll(dat, 1, 1000);
        if (r < 0) {
            fprintf(stderr, "receive: %s\n", mikrocRS485_strerror(r));
            status = 1;
            break;
        }
        if (r == 0) {
            if (++silent == 5) {
                fprintf(stderr, "slave 160 does not answer\n");
                status = 1;
                break;
            }
            fprintf(stderr, "no answer from slave 160, sending again\n");
            RS485Master_Send(dat, 1, (char)160);
            continue;
        }
        silent = 0;
        if (dat[5]) {             /* if an error detected, signal it */
            printf("error: %s\n", mikrocRS485_strerror(mikrocRS485_LastRxError(1)));
            dat[5] = 0;
        }
        if (dat[4]) {             /* upon completed valid message receiving */
            dat[4] = 0;           /* data[4] is set to 255 */
            unsigned char j = (unsigned char)dat[0];
            printf("slave %u says 0x%02X\n", (unsigned char)dat[6], j);
            dat[0] = (char)(j + 1);       /* increment received dat[0] */
            RS485Master_Send(dat, 1, (char)160);     /* send back to slave */
            done++;
        }
    }
    mikrocRS485_Close();
    return status;
}
