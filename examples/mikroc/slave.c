/* mikroC RS-485 slave example, on a Linux host.
 *
 * The vendor's slave example answers every message from the master with
 * the first byte incremented. Here the UART interrupt that calls
 * RS485Slave_Receive() is a loop around mikrocRS485_Poll().
 *
 *   mikroc_slave DEVICE [BAUD [ROUNDS]]      (slave address 160)
 */
#include <stdio.h>
#include <stdlib.h>

#include <mikroc_rs485.h>

char dat[9];                      /* buffer for receiving/sending messages */

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
    RS485Slave_Init((char)160);   /* initialize MCU as Slave with address 160 */

    dat[4] = 0;                   /* ensure that message received flag is 0 */
    dat[5] = 0;                   /* make sure error flag is 0 */
    dat[6] = 0;
    printf("slave 160 listening on %s\n", argv[1]);
    fflush(stdout);

    int status = 0;
    for (int done = 0; done < rounds;) {
        r = mikrocRS485_Poll(dat, 0, 5000);
        if (r < 0) {
            fprintf(stderr, "receive: %s\n", mikrocRS485_strerror(r));
            status = 1;
            break;
        }
        if (r == 0) {
            fprintf(stderr, "no message for 5 s\n");
            status = 1;
            break;
        }
        if (dat[5]) {             /* if an error detected, signal it */
            printf("error: %s\n", mikrocRS485_strerror(mikrocRS485_LastRxError(0)));
            dat[5] = 0;
        }
        if (dat[4]) {             /* upon completed valid message receive */
            dat[4] = 0;           /* data[4] is set to 0xFF */
            unsigned char j = (unsigned char)dat[0];
            printf("master says 0x%02X\n", j);
            fflush(stdout);
            dat[0] = (char)(j + 1);       /* increment received dat[0] */
            RS485Slave_Send(dat, 1);      /* and send it back to master */
            done++;
        }
    }
    mikrocRS485_Close();
    return status;
}
