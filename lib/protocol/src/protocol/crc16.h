// CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, xorout 0, check("123456789") = 0x29B1.
#ifndef PROTOCOL_CRC16_H
#define PROTOCOL_CRC16_H

#include <stdint.h>

namespace proto {

static const uint16_t kCrcInit = 0xFFFFu;

// One byte, table-free (same arithmetic as avr-libc's _crc_xmodem_update; ~20 AVR cycles).
inline uint16_t crc16_update(uint16_t crc, uint8_t byte) {
    crc = static_cast<uint16_t>((crc >> 8) | (crc << 8));
    crc ^= byte;
    crc ^= static_cast<uint16_t>((crc & 0xFFu) >> 4);
    crc ^= static_cast<uint16_t>(crc << 12);
    crc ^= static_cast<uint16_t>((crc & 0xFFu) << 5);
    return crc;
}

uint16_t crc16(const uint8_t* data, uint16_t len, uint16_t crc = kCrcInit);

}  // namespace proto

#endif  // PROTOCOL_CRC16_H
