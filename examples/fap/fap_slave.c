/*------------------------------------------------------------------------*/
/* File Name   : fap_slave.c                                              */
/* Description : Example FAP Slave, written as the vendor document's      */
/*               examples are: answers every message with a reply to its  */
/*               sender.                                                   */
/* Usage       : fap_slave [device [id [count]]]                          */
/*               default /dev/ttyS1, id 7, run forever (count 0)          */
/* Build       : cc fap_slave.c -o fap_slave -lfap -lpthread -lrt         */
/*------------------------------------------------------------------------*/
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <fap.h>
#include <fapx.h>   /* fapClassicClose: libfap's addition, the vendor API has no close */

static const char usage[] =
    "usage: fap_slave [device [id [count]]]\n"
    "  device  serial port (default /dev/ttyS1)\n"
    "  id      slave ID 1..31 (default 7)\n"
    "  count   messages to answer (0 = forever) (default 0)\n" ;

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
    long   count   = argc > 3 ? number (argv[3]) : 0 ;
    usys   myId ;
    int    handled = 0 ;

    if (argc > 4 || (argc > 1 && argv[1][0] == '-') || id < 1 || id > 31 || count < 0)
    {
       fputs (usage, stderr) ;
       return 2 ;
    }
    if (argc == 1)   /* no arguments: say what runs */
       fprintf (stderr, "%s(no arguments: /dev/ttyS1, id 7, count 0)\n", usage) ;
    myId = (usys) id ;

    status = fapInit (devName, 115200) ;
    if (status != GOOD)
    {
       printf ("ERROR: fapInit() Failed with Status %d !!!\n", status) ;
       return BAD ;
    }

    config.mode    = FAP_SLAVE ;
    config.id      = myId ;
    config.idcTime = 0 ;
    status = fapConfig (&config) ;
    if (status != GOOD)
    {
       printf ("ERROR: fapConfig() Failed with Status %d !!!\n", status) ;
       fapClassicClose () ;
       return BAD ;
    }
    printf ("slave %u ready\n", myId) ;
    fflush (stdout) ;

    while (count == 0 || handled < count)
    {
       u8   rxData [MAX_DATA_SIZE + 1] ;
       u8   reply [MAX_DATA_SIZE] ;
       usys rxSize, rxId, len ;

       status = fapRx (rxData, &rxSize, &rxId) ;
       if (status == E_RES)
       {
          usleep (1000) ;           /* nothing yet: fapRx is non-blocking */
          continue ;
       }
       if (status != GOOD)
       {
          printf ("ERROR: fapRx() Failed with Status %d !!!\n", status) ;
          fapClassicClose () ;
          return BAD ;
       }
       rxData[rxSize] = 0 ;
       printf ("slave %u received from %u: %s\n", myId, rxId, (char *) rxData) ;
       fflush (stdout) ;

       len = (usys) snprintf ((char *) reply, sizeof reply, "slave %u got: %s", myId, (char *) rxData) ;
       if (len > MAX_DATA_SIZE)
          len = MAX_DATA_SIZE ;
       while ((status = fapTx (reply, len, rxId)) == E_RES)
          usleep (1000) ;           /* transmit buffers full: wait for our turn */
       if (status != GOOD)
       {
          printf ("ERROR: fapTx() Failed with Status %d !!!\n", status) ;
          fapClassicClose () ;
          return BAD ;
       }
       handled++ ;
    }

    /* let the last reply go out at our next SEND_DATA before exiting */
    sleep (1) ;
    fapClassicClose () ;
    return GOOD ;
}
