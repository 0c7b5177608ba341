// CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, xorout 0, check("123456789") = 0x29B1.
#ifndef PROTOCOL_CRC16_H
#define PROTOCOL_CRC16_H

#include <stdint.h>
#if defined(__AVR__)
#include <util/crc16.h>  // avr-libc: _crc_xmodem_update, the same per-byte step in inline asm
#endif

namespace proto {

static const uint16_t kCrcInit = 0xFFFFu;

// One byte, table-free. XMODEM and CCITT-FALSE share this step (poly 0x1021, unreflected);
// they differ only in the initial value, which the caller passes (kCrcInit).
inline uint16_t crc16_update(uint16_t crc, uint8_t byte) {
#if defined(__AVR__)
    return _crc_xmodem_update(crc, byte);
#else
    crc = static_cast<uint16_t>((crc >> 8) | (crc << 8));
    crc ^= byte;
    crc ^= static_cast<uint16_t>((crc & 0xFFu) >> 4);
    crc ^= static_cast<uint16_t>(crc << 12);
    crc ^= static_cast<uint16_t>((crc & 0xFFu) << 5);
    return crc;
#endif
}

uint16_t crc16(const uint8_t* data, uint16_t len, uint16_t crc = kCrcInit);

}  // namespace proto

#endif  // PROTOCOL_CRC16_H
