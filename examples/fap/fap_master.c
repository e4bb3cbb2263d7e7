/*------------------------------------------------------------------------*/
/* File Name   : fap_master.c                                             */
/* Description : Example FAP Master, written as the vendor document's     */
/*               examples are: fapInit, fapConfig, fapAddSlave, then      */
/*               fapTx / fapRx (non-blocking, polled).                    */
/* Usage       : fap_master [device [slaveId [count]]]                    */
/*               default /dev/ttyS1, slave 7, 10 messages                 */
/* Build       : cc fap_master.c -o fap_master -lfap -lpthread -lrt       */
/*------------------------------------------------------------------------*/
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <fap.h>
#include <fapx.h>   /* fapClassicClose: libfap's addition, the vendor API has no close */

#define REPLY_WAIT_MS  20000

static const char usage[] =
    "usage: fap_master [device [slaveId [count]]]\n"
    "  device  serial port (default /dev/ttyS1)\n"
    "  slaveId slave ID 1..31 (default 7)\n"
    "  count   messages to send (>= 1) (default 10)\n" ;

/* a decimal argument, -1 when it is not one */
static long number (const char *s)
{
    char *end ;
    long  v = strtol (s, &end, 10) ;
    return (*s && !*end && v >= 0 && v <= INT_MAX) ? v : -1 ;
}

int main (int argc, char **argv)
{
    usys   status ;
    fapT   config ;
    char  *devName = argc > 1 ? argv[1] : "/dev/ttyS1" ;
    long   id      = argc > 2 ? number (argv[2]) : 7 ;
    long   count   = argc > 3 ? number (argv[3]) : 10 ;
    usys   slaveId ;
    int    replies = 0 ;
    int    i, waited ;

    if (argc > 4 || (argc > 1 && argv[1][0] == '-') || id < 1 || id > 31 || count < 1)
    {
       fputs (usage, stderr) ;
       return 2 ;
    }
    if (argc == 1)   /* no arguments: say what runs */
       fprintf (stderr, "%s(no arguments: /dev/ttyS1, slaveId 7, count 10)\n", usage) ;
    slaveId = (usys) id ;

    /* Configure the RS-485 Port (closed at every return below: the port
       gets its original RS-485 configuration back) */
    status = fapInit (devName, 115200) ;
    if (status != GOOD)
    {
       printf ("ERROR: fapInit() Failed with Status %d !!!\n", status) ;
       return BAD ;
    }

    config.mode    = FAP_MASTER ;
    config.id      = 0  ;
    config.idcTime = 15 ;
    status = fapConfig (&config) ;
    if (status != GOOD)
    {
       printf ("ERROR: fapConfig() Failed with Status %d !!!\n", status) ;
       fapClassicClose () ;
       return BAD ;
    }

    status = fapAddSlave (slaveId) ;
    if (status != GOOD)
    {
       printf ("ERROR: fapAddSlave(%u) Failed with Status %d !!!\n", slaveId, status) ;
       fapClassicClose () ;
       return BAD ;
    }

    for (i = 0 ; i < count ; i++)
    {
       u8   msg [MAX_DATA_SIZE] ;
       u8   rxData [MAX_DATA_SIZE + 1] ;
       usys rxSize, rxId ;

       sprintf ((char *) msg, "hello %d from the master", i) ;
       status = fapTx (msg, (usys) strlen ((char *) msg), slaveId) ;
       if (status != GOOD)
       {
          printf ("ERROR: fapTx() Failed with Status %d !!!\n", status) ;
          fapClassicClose () ;
          return BAD ;
       }

       /* fapRx is non-blocking: poll it */
       for (waited = 0 ; waited < REPLY_WAIT_MS ; waited++)
       {
          status = fapRx (rxData, &rxSize, &rxId) ;
          if (status == GOOD)
             break ;
          usleep (1000) ;
       }
       if (status != GOOD)
       {
          printf ("ERROR: no reply from slave %u !!!\n", slaveId) ;
          break ;
       }
       rxData[rxSize] = 0 ;
       printf ("reply from %u: %s\n", rxId, (char *) rxData) ;
       if (rxId == slaveId)
          replies++ ;
    }

    printf ("master: %d of %ld replies\n", replies, count) ;
    fapClassicClose () ;
    return replies == count ? GOOD : BAD ;
}
