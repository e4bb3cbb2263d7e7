/* Written as the vendor document's examples are: <fap.h>, fapInit on a
 * device, fapConfig as a master. Built against an installed prefix with
 * `cc vendor_app.c -lfap -lpthread -lrt` and via pkg-config. Run with a
 * device that does not exist it must report BAD from fapInit. */
#include <stdio.h>
#include <fap.h>

int main(int argc, char **argv)
{
    usys status ;
    fapT config ;
    char *dev = argc > 1 ? argv[1] : "/dev/ttyS1" ;

    /* before fapInit every call reports E_INIT */
    config.mode    = FAP_MASTER ;
    config.id      = 0 ;
    config.idcTime = 15 ;
    status = fapConfig (&config) ;
    if (status != E_INIT)
    {
       printf ("ERROR: fapConfig() before fapInit() gave %d !!!\n", status) ;
       return BAD ;
    }

    status = fapInit (dev, 115200) ;
    if (status != GOOD)
    {
       printf ("ERROR: fapInit() Failed with Status %d !!!\n", status) ;
       return status == BAD ? 0 : 1 ;
    }
    printf ("fapInit(%s) GOOD\n", dev) ;
    return 0 ;
}
