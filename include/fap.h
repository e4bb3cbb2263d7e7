/*------------------------------------------------------------------------*/
/*                                                                        */
/* File Name       : fap.h                                                */
/* Description     : FAP Driver Interface                                 */
/* Notes           : libfap reimplementation of the vendor interface file.*/
/*                   fapInit takes (devName, baudRate) as in section 4.5  */
/*                   of the vendor document (its listing says (void)).    */
/*                   The re-entrant handle API is in <fapx.h>.            */
/*                                                                        */
/*------------------------------------------------------------------------*/
#ifndef  FAP_H
#define  FAP_H

#ifdef __cplusplus
extern "C" {
#endif

typedef  unsigned char  u8   ;
typedef           char  s8   ;
typedef  unsigned short u16  ;
typedef           short s16  ;
typedef  unsigned long  u32  ;
typedef           long  s32  ;
typedef  unsigned int   usys ;
typedef           int   ssys ;

#define  GOOD     0

/* Error codes */
#define  BAD        1
#define  E_PARAM    2
#define  E_VALUE    3
#define  E_INIT     4
#define  E_RES      5

/* MODES */
#define  FAP_MASTER 0
#define  FAP_SLAVE  1

typedef  struct    fapT
{
    usys id        ;
    usys mode      ;
    usys idcTime   ;
 } fapT ;

#define  MAX_SLAVES      32
#define  MAX_DATA_SIZE   1024

/* API */
extern   usys      fapInit      (char *devName, usys baudRate) ;
extern   usys      fapAddSlave  (usys id) ;
extern   usys      fapRemSlave  (usys id) ;
extern   usys      fapConfig    (fapT *config) ;
extern   usys      fapTx        (u8 *data, usys  size, usys  id) ;
extern   usys      fapRx        (u8 *data, usys *size, usys *id) ;

#ifdef __cplusplus
}
#endif

#endif /* ! FAP_H */
