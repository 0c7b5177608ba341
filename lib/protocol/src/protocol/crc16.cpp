#include <protocol/crc16.h>

namespace proto {

uint16_t crc16(const uint8_t* data, uint16_t len, uint16_t crc) {
    for (uint16_t i = 0; i < len; ++i) crc = crc16_update(crc, data[i]);
    return crc;
}

}  // namespace proto
