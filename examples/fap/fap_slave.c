/*------------------------------------------------------------------------*/
/* File Name   : fap_slave.c                                              */
/* Description : Example FAP Slave, written as the vendor document's      */
/*               examples are: answers every message with a reply to its  */
/*               sender.                                                   */
/* Usage       : fap_slave [device [id [count]]]                          */
/*               default /dev/ttyS1, id 7, run forever (count 0)          */
/* Build       : cc fap_slave.c -o fap_slave -lfap -lpthread -lrt         */
/*------------------------------------------------------------------------*/
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <fap.h>
#include <fapx.h>   /* fapClassicClose: libfap's addition, the vendor API has no close */

int main (int argc, char **argv)
{
    usys   status ;
    fapT   config ;
    char  *devName = argc > 1 ? argv[1] : "/dev/ttyS1" ;
    usys   myId    = argc > 2 ? (usys) atoi (argv[2]) : 7 ;
    int    count   = argc > 3 ? atoi (argv[3]) : 0 ;
    int    handled = 0 ;

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
