/* CRC-16 variants used by the wire protocols. Pure functions, no I/O. */
#ifndef LF_CRC16_H
#define LF_CRC16_H
#include <stddef.h>
#include <stdint.h>

/* CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, not reflected (FAP). */
#define LF_CRC_CCITT_INIT 0xFFFFu
uint16_t lf_crc16_ccitt_update(uint16_t crc, const uint8_t *p, size_t n);
static inline uint16_t lf_crc16_ccitt(const uint8_t *p, size_t n)
{
    return lf_crc16_ccitt_update(LF_CRC_CCITT_INIT, p, n);
}

/* CRC-16/ARC: poly 0x8005 reflected (0xA001), init 0 (exec async). */
uint16_t lf_crc16_arc_update(uint16_t crc, const uint8_t *p, size_t n);
static inline uint16_t lf_crc16_arc(const uint8_t *p, size_t n)
{
    return lf_crc16_arc_update(0, p, n);
}
#endif
